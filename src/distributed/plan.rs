//! A split render's plan: what one `render` command asks ([`Request`]) made into the region it
//! renders of every frame and its [`Job`]s, one per output (a frame, or the still), each with
//! its file, its scene time, where its state goes, and whether it is skipped, resumed or
//! started afresh. The checks come in the order `render` has always made them, so that the
//! first error of a request is the one reported, and every one names the flag at fault.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::film_file::{PieceError, PieceInfo, piece_info, read_info, read_piece, write_piece, write_piece_quickly};
use super::frames::{frame_path, has_frame_pattern};
use super::overwrite::{Named, check_overwrites};
use crate::device::{DeviceError, RenderedFrame, Renderer};
use crate::image_io::{ImageError, check_output_path, write_image};
use crate::memory::OutOfMemory;
use crate::render::pass::{Pass, Progress};
use crate::render::region::{Rect, Region, tile_rect};
use crate::scene::{RenderSettings, Scene};

/// What one `render` command asks of a scene, its flags already read: the settings (the
/// scene's `[render]` table with the flags' overrides), which part of each frame to render,
/// which frames, and where.
#[derive(Clone, Debug)]
pub struct Request {
    /// The scene file, as errors name it.
    pub scene: PathBuf,
    /// The output: an image, or a partial film (`.exr`) for a split render; `%04d` (or `%d`,
    /// `%0Nd`) becomes the frame number.
    pub output: PathBuf,
    pub settings: RenderSettings,
    /// `--tile I/N`: tile I of the grid of N ([`tile_rect`]).
    pub tile: Option<(u32, u32)>,
    /// `--crop`: a rectangle of the image (ignored where `tile` is given).
    pub crop: Option<Rect>,
    /// `--samples A..B`: the sample indices of every pixel (default: all of `settings.spp`).
    pub samples: Option<Range<u32>>,
    /// `--frames A..B` (`--frame N` is `N..N+1`). `None`: the scene's frame range where the
    /// output name has a frame pattern, else a still at the first frame.
    pub frames: Option<Range<u32>>,
    /// `--checkpoint SECONDS`: how often a job writes its state.
    pub checkpoint: Option<f64>,
    /// `--resume`: carry on from a job's state where there is one.
    pub resume: bool,
    /// `--skip-existing`: do nothing for an output already complete.
    pub skip_existing: bool,
}

impl Request {
    /// Whether this is a split render (`--tile`, `--crop` or `--samples`): its outputs are
    /// partial films, and their state is the output itself.
    pub fn is_split(&self) -> bool {
        self.tile.is_some() || self.crop.is_some() || self.samples.is_some()
    }
}

/// A request found wrong before any work, with the message `render` prints. All but
/// [`PlanError::Memory`] (exit code 3), [`PlanError::Unwritable`] and the I/O cases of
/// [`PlanError::Output`] and [`PlanError::State`] are bad input (exit code 2).
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("--spp and --max-depth must be at least 1")]
    NoSamples,
    #[error("--clamp must be a radiance > 0")]
    Clamp,
    #[error("--time must be a number of seconds > 0")]
    Time,
    #[error("--checkpoint must be a number of seconds > 0")]
    Checkpoint,
    #[error("--tile {i}/{n}: the tile number must be below {n} (tiles count from 0)")]
    TileNumber { i: u32, n: u32 },
    /// `resolution` names the scene file, line and key of the image size.
    #[error("--tile {i}/{n}: a {width}x{height} image has no grid of {n} tiles ({resolution})")]
    NoTileGrid { i: u32, n: u32, width: u32, height: u32, resolution: String },
    #[error("--crop {rect}: not inside the image ({resolution})")]
    Crop { rect: Rect, resolution: String },
    #[error("--samples {}..{}: past the render's {spp} samples per pixel (render.spp in {}, or --spp)", samples.start, samples.end, scene.display())]
    Samples { samples: Range<u32>, spp: u32, scene: PathBuf },
    /// The film of the region does not fit in memory.
    #[error(transparent)]
    Memory(#[from] OutOfMemory),
    /// The output's name is not one of an image format.
    #[error(transparent)]
    Output(#[from] ImageError),
    #[error("-o {}: a split render (--tile, --crop or --samples) writes a partial film, an EXR: name it .exr", output.display())]
    SplitNotExr { output: PathBuf },
    #[error("-o {}: more than one frame pattern (%d or %0Nd) in the name", output.display())]
    FramePatterns { output: PathBuf },
    /// The first output's folder cannot be made or written.
    #[error("cannot write {}", path.display())]
    Unwritable {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// `from` is `--frames`, or the scene's `animation.frames` where the range came from there.
    #[error("{from} {}..{}: {} frames in one command; at most {MAX_FRAMES} (split the range into several commands)", frames.start, frames.end, frames.len())]
    TooManyFrames { frames: Range<u32>, from: String },
    /// An output would replace a file the run reads, or another of its outputs.
    #[error(transparent)]
    Overwrite(#[from] super::overwrite::Overwrite),
    #[error("{count} frames would all go to {}: put a frame pattern such as %04d in the output name", output.display())]
    NoFramePattern { count: usize, output: PathBuf },
    /// `--resume` found a state of another render.
    #[error("--resume: {} is a piece of another render: {why}", state.display())]
    ForeignState { state: PathBuf, why: String },
    /// `--resume` found a partial film of this very piece, already complete.
    #[error("--resume: {} is finished (samples {}..{}): nothing to resume; --skip-existing skips finished outputs", state.display(), samples.start, samples.end)]
    Finished { state: PathBuf, samples: Range<u32> },
    /// `--resume` could not read the state.
    #[error(transparent)]
    State(#[from] PieceError),
}

/// What can stop a job once it renders.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// Writing the output or the state failed.
    #[error(transparent)]
    Write(#[from] ImageError),
    /// A whole render's state (`OUT.partial.exr`) could not be removed once the image was written.
    #[error("cannot remove {}", path.display())]
    Remove {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Stopped (a signal raised the stop flag) after writing its state.
    #[error("stopped by a signal after {done} of {of} samples per pixel; the state is in {}: run again with --resume to finish", state.display())]
    Interrupted { state: PathBuf, done: u32, of: u32 },
}

/// The most frames one command renders: about 4.6 days of animation at 24 frames a second.
/// A range beyond it is a typo (`0..4000000000`), not a job.
pub const MAX_FRAMES: usize = 10_000_000;

/// A request checked against its scene: the region every job renders.
#[derive(Clone, Debug)]
pub struct Plan {
    pub request: Request,
    /// The rectangle and sample indices rendered of every frame.
    pub region: Region,
    /// The image's size.
    pub width: u32,
    pub height: u32,
}

impl Plan {
    /// Checks `request`'s settings and region against `scene` (loaded from `request.scene`).
    pub fn new(request: Request, scene: &Scene) -> Result<Plan, PlanError> {
        let settings = &request.settings;
        if settings.spp == 0 || settings.max_depth == 0 {
            return Err(PlanError::NoSamples);
        }
        if settings.clamp.is_some_and(|c| !(c.is_finite() && c > 0.0)) {
            return Err(PlanError::Clamp);
        }
        if settings.time.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
            return Err(PlanError::Time);
        }
        if request.checkpoint.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
            return Err(PlanError::Checkpoint);
        }
        let region = region(&request, scene)?;
        let (width, height) = (scene.camera.width, scene.camera.height);
        Ok(Plan { request, region, width, height })
    }

    /// The frames to render (`None`: a still, at the scene's first frame, of the scene as
    /// built), once it is checked, before any work, that the region's film fits in memory and
    /// that the outputs can be written: the output's name, and the first output's folder
    /// (made, as [`crate::atomic_file::prepare`] does).
    pub fn frames(&self, scene: &Scene) -> Result<Option<Range<u32>>, PlanError> {
        // The film's sums, a pass's (dropped if a signal cuts it), the tiles' and the image
        // written: about four times a pixel's sums.
        let film_bytes =
            self.region.rect.pixel_count() as f64 * 4.0 * size_of::<crate::render::film::PixelAccum>() as f64;
        crate::memory::check_fits(&format!("{}: the image", resolution(&self.request, scene)), film_bytes)?;
        check_outputs(&self.request, scene)
    }

    /// What the partial film of `frame` says of itself, before any sample: `scene_hash` is
    /// [`Scene::content_hash`], `device` [`crate::device::Device::name`].
    pub fn piece(&self, scene_hash: &str, device: &str, frame: Option<u32>) -> PieceInfo {
        let s = &self.request.settings;
        PieceInfo {
            scene_hash: scene_hash.to_owned(),
            seed: s.seed,
            max_depth: s.max_depth,
            clamp: s.clamp,
            width: self.width,
            height: self.height,
            frame,
            device: device.to_owned(),
            rect: self.region.rect,
            samples: self.region.samples.clone(),
            done: self.region.samples.start,
            rays: 0,
            seconds: 0.0,
        }
    }

    /// The jobs, one per output of `frames` ([`Plan::frames`]), in frame order, made as they are
    /// taken (a range may hold millions); `scene_hash` and `device` as for [`Plan::piece`].
    pub fn jobs<'a>(
        &'a self,
        frames: Option<Range<u32>>,
        scene: &'a Scene,
        scene_hash: &'a str,
        device: &'a str,
    ) -> impl ExactSizeIterator<Item = Job> + 'a {
        let frames: Box<dyn ExactSizeIterator<Item = Option<u32>>> = match frames {
            None => Box::new(std::iter::once(None)),
            Some(frames) => Box::new(frames.map(Some)),
        };
        frames.map(move |frame| self.job(frame, scene, scene_hash, device))
    }

    /// The job of `frame` (`None`: the still); `scene_hash` and `device` as for [`Plan::piece`].
    pub fn job(&self, frame: Option<u32>, scene: &Scene, scene_hash: &str, device: &str) -> Job {
        let (output, time) = match frame {
            None => (self.request.output.clone(), crate::render::first_frame_time(scene)),
            Some(f) => (frame_path(&self.request.output, f), scene.frame_time(f)),
        };
        let split = self.request.is_split();
        Job {
            state: if split { output.clone() } else { sidecar(&output) },
            output,
            time,
            frame,
            piece: self.piece(scene_hash, device, frame),
            region: self.region.clone(),
            settings: self.request.settings,
            split,
            resume: self.request.resume,
            skip_existing: self.request.skip_existing,
            checkpoint: self.request.checkpoint,
        }
    }

    /// Checks, before any work, that no output of `frames` (images or pieces, their states)
    /// nor `report` replaces one of `inputs` (the files the run reads) or another output.
    pub fn check_overwrites(
        &self,
        frames: Option<&Range<u32>>,
        inputs: &[Named],
        report: Option<&Path>,
    ) -> Result<(), PlanError> {
        let mut outputs = vec![Named::new("-o", &self.request.output)];
        if !self.request.is_split() {
            outputs.push(Named::new("-o's state", sidecar(&self.request.output)));
        }
        outputs.extend(report.map(|r| Named::new("--report", r)));
        Ok(check_overwrites(&outputs, frames, inputs)?)
    }
}

/// `SCENE:LINE: camera.resolution WxH`, where errors about the image's size point.
fn resolution(request: &Request, scene: &Scene) -> String {
    let c = &scene.camera;
    format!("{}:{}: camera.resolution {}x{}", request.scene.display(), c.resolution_line, c.width, c.height)
}

/// What the request renders of each frame.
fn region(request: &Request, scene: &Scene) -> Result<Region, PlanError> {
    let (width, height) = (scene.camera.width, scene.camera.height);
    let rect = match (request.tile, request.crop) {
        (Some((i, n)), _) => tile_rect(i, n, width, height).ok_or_else(|| {
            if i >= n {
                PlanError::TileNumber { i, n }
            } else {
                PlanError::NoTileGrid { i, n, width, height, resolution: resolution(request, scene) }
            }
        })?,
        (None, Some(r)) if r.fits(width, height) => r,
        (None, Some(rect)) => return Err(PlanError::Crop { rect, resolution: resolution(request, scene) }),
        (None, None) => Rect::full(width, height),
    };
    let spp = request.settings.spp;
    let samples = request.samples.clone().unwrap_or(0..spp);
    if samples.end > spp {
        return Err(PlanError::Samples { samples, spp, scene: request.scene.clone() });
    }
    Ok(Region { rect, samples })
}

/// Checks the output's name and the first output's folder (in the nearest folder that exists),
/// and returns the frames: a name with two frame patterns, of which only the first would be
/// replaced, is refused, and so are several frames to one file.
fn check_outputs(request: &Request, scene: &Scene) -> Result<Option<Range<u32>>, PlanError> {
    let output = &request.output;
    check_output_path(output)?;
    if request.is_split() && !output.to_string_lossy().to_ascii_lowercase().ends_with(".exr") {
        return Err(PlanError::SplitNotExr { output: output.clone() });
    }
    let frames = match &request.frames {
        Some(r) => Some(r.clone()),
        None if has_frame_pattern(output) => Some(scene.animation.as_ref().map_or(0..1, |a| a.frames.clone())),
        None => None,
    };
    let first = frames.as_ref().map_or_else(|| output.clone(), |r| frame_path(output, r.start));
    if let Some(f) = frames.as_ref().filter(|f| f.len() > MAX_FRAMES) {
        let from = if request.frames.is_some() {
            "--frames".to_owned()
        } else {
            format!("animation.frames in {}", request.scene.display())
        };
        return Err(PlanError::TooManyFrames { frames: f.clone(), from });
    }
    if frames.is_some() && has_frame_pattern(&first) {
        return Err(PlanError::FramePatterns { output: output.clone() });
    }
    crate::atomic_file::prepare(&first).map_err(|source| PlanError::Unwritable { path: first, source })?;
    if let Some(f) = frames.as_ref().filter(|f| f.len() > 1 && !has_frame_pattern(output)) {
        return Err(PlanError::NoFramePattern { count: f.len(), output: output.clone() });
    }
    Ok(frames)
}

/// Where a whole render keeps its state: `OUT.partial.exr`.
pub fn sidecar(output: &Path) -> PathBuf {
    let mut name = output.as_os_str().to_owned();
    name.push(".partial.exr");
    PathBuf::from(name)
}

/// One output of a planned render: a frame, or the still.
#[derive(Clone, Debug)]
pub struct Job {
    pub output: PathBuf,
    /// The scene time it shows.
    pub time: f32,
    /// The frame number (`None` for a still).
    pub frame: Option<u32>,
    /// Where its state goes: the output itself for a partial film, else `OUT.partial.exr`
    /// ([`sidecar`]).
    pub state: PathBuf,
    /// What its partial film (output or state) says of itself before any sample.
    pub piece: PieceInfo,
    pub region: Region,
    pub settings: RenderSettings,
    /// Whether the output is a partial film.
    pub split: bool,
    pub resume: bool,
    pub skip_existing: bool,
    pub checkpoint: Option<f64>,
}

/// How a job starts.
pub enum Start {
    /// Its output is complete and `--skip-existing` was given: nothing to do.
    Skip,
    /// From no sample.
    Fresh,
    /// From the samples of its state (`--resume`).
    Resume(RenderedFrame),
    /// From no sample, its state (`--resume`) unreadable: damaged, altered, cut short or of an
    /// older format (`why`). A state is only a shortcut: it is rendered again, and replaced.
    Restart(PieceError),
}

/// Whether `e`, reading a state, says the file is not a whole piece (as opposed to a failing
/// disk, worth a retry, or too little memory).
fn is_damage(e: &PieceError) -> bool {
    !matches!(e, PieceError::Io { .. } | PieceError::Memory(_))
}

impl Job {
    /// Whether the output already holds this job, complete and whole: for a partial film, a
    /// piece of this very render with all its samples, whose sums pass their checks and its
    /// integrity digest; for an image, a file that decodes to an image of the right size (an
    /// output cut short by a full disk or a copy is not complete).
    pub fn is_complete(&self) -> bool {
        if !self.split {
            return crate::image_io::is_whole_image(&self.output, self.piece.width, self.piece.height);
        }
        matches!(read_info(&self.output), Ok(Some(info)) if info.same_piece(&self.piece) && info.is_complete())
            && read_piece(&self.output).is_ok()
    }

    /// Whether the job does nothing: `skip_existing` was given and the output is complete
    /// ([`Job::is_complete`]).
    pub fn skips(&self) -> bool {
        self.skip_existing && self.is_complete()
    }

    /// Whether the job carries on from a state (`resume`, and a state is there), its header
    /// checked: a state of another render, or (for a partial film, without `skip_existing`) one
    /// already complete, is an error. Reads no pixels: a render checks every job this way before
    /// any work. A state that cannot be read back (damaged, altered, of an older format) is no
    /// state: the job starts afresh ([`Start::Restart`]).
    pub fn check_state(&self) -> Result<bool, PlanError> {
        if !self.resume || !self.state.exists() {
            return Ok(false);
        }
        let theirs = match piece_info(&self.state) {
            Ok(info) => info,
            Err(e) if is_damage(&e) => return Ok(false),
            Err(e) => return Err(e.into()),
        };
        if self.renders_again(&theirs) {
            return Ok(false);
        }
        self.check_same(&theirs)?;
        Ok(true)
    }

    /// Whether the state `theirs` says is this very piece, complete, yet the job did not skip
    /// it under `skip_existing`: then it is not whole (damaged, or rewritten meanwhile), and the
    /// piece is rendered again rather than refused as finished.
    fn renders_again(&self, theirs: &PieceInfo) -> bool {
        self.split && self.skip_existing && theirs.is_complete() && theirs.same_piece(&self.piece)
    }

    fn check_same(&self, theirs: &PieceInfo) -> Result<(), PlanError> {
        let ours = &self.piece;
        if !theirs.same_piece(ours) {
            let why = match ours.differs_from(theirs) {
                Some((what, ours, theirs)) => format!("its {what} is {theirs}, this render's {ours}"),
                None => format!(
                    "it holds pixels {} and samples {:?}, this render {} and {:?}",
                    theirs.rect, theirs.samples, ours.rect, ours.samples
                ),
            };
            return Err(PlanError::ForeignState { state: self.state.clone(), why });
        }
        if self.split && theirs.is_complete() {
            return Err(PlanError::Finished { state: self.state.clone(), samples: theirs.samples.clone() });
        }
        Ok(())
    }

    /// How the job starts: skipped where it [`skips`](Job::skips); carried on from its state
    /// where `resume` and there is one (checked as [`Job::check_state`] does, and read whole,
    /// its integrity checked), or afresh where that state cannot be read back
    /// ([`Start::Restart`]); else afresh.
    pub fn start(&self) -> Result<Start, PlanError> {
        if self.skips() {
            return Ok(Start::Skip);
        }
        if !self.resume || !self.state.exists() {
            return Ok(Start::Fresh);
        }
        let piece = match read_piece(&self.state) {
            Ok(piece) => piece,
            Err(e) if is_damage(&e) => return Ok(Start::Restart(e)),
            Err(e) => return Err(e.into()),
        };
        if self.renders_again(&piece.info) {
            return Ok(Start::Fresh);
        }
        self.check_same(&piece.info)?;
        Ok(Start::Resume(RenderedFrame {
            samples: piece.info.done - piece.info.samples.start,
            rays: piece.info.rays,
            seconds: piece.info.seconds,
            film: piece.film,
            timed_seconds: 0.0,
        }))
    }

    /// What the partial film of `frame`, a render of this job, holds.
    pub fn held(&self, frame: &RenderedFrame) -> PieceInfo {
        PieceInfo {
            done: self.piece.samples.start + frame.samples,
            rays: frame.rays,
            seconds: frame.seconds,
            ..self.piece.clone()
        }
    }

    /// Renders the job's region on `renderer` (moved to [`Job::time`] by the caller), carrying
    /// on from `carried`. Every `checkpoint` seconds, and when `stop` is raised (a signal), the
    /// render pauses after its pass and its state goes to [`Job::state`] (a partial film,
    /// written atomically); once `stop` is raised, the job ends there with
    /// [`JobError::Interrupted`].
    pub fn render(
        &self,
        renderer: &mut Renderer,
        mut carried: Option<RenderedFrame>,
        progress: &(dyn Fn(Progress) + Sync),
        stop: &AtomicBool,
    ) -> Result<RenderedFrame, JobError> {
        let stopped = || stop.load(Ordering::Relaxed);
        let (region, settings) = (&self.region, &self.settings);
        let wanted = region.samples.len() as u32;
        loop {
            let since = Instant::now();
            let pause = |_| stopped() || self.checkpoint.is_some_and(|c| since.elapsed().as_secs_f64() >= c);
            // A signal abandons the pass in flight: the state written is the last whole pass.
            let pass = Pass::new(settings, region.clone())
                .carrying(carried.take())
                .with_progress(progress)
                .with_pause(&pause)
                .with_abandon(&stopped);
            let frame = renderer.render_region(pass)?;
            let out_of_time = settings.time.is_some_and(|t| frame.seconds >= t);
            if frame.samples == wanted || out_of_time {
                return Ok(frame);
            }
            if stopped() {
                write_piece_quickly(&self.state, &self.held(&frame), &frame.film)?;
                let done = region.samples.start + frame.samples;
                return Err(JobError::Interrupted { state: self.state.clone(), done, of: region.samples.end });
            }
            write_piece(&self.state, &self.held(&frame), &frame.film)?;
            carried = Some(frame);
        }
    }

    /// Writes `frame`, this job rendered: a partial film, or the image (missing folders are
    /// made, each frame's where the pattern names folders), after which a whole render's state
    /// is removed.
    pub fn write(&self, frame: &RenderedFrame) -> Result<(), JobError> {
        if self.split {
            write_piece(&self.output, &self.held(frame), &frame.film)?;
            return Ok(());
        }
        write_image(&self.output, &frame.film.mean())?;
        match std::fs::remove_file(&self.state) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(JobError::Remove { path: self.state.clone(), source: e })
            }
            _ => Ok(()),
        }
    }
}
