//! One entry point for rendering on the CPU or the GPU: [`Renderer`].
//!
//! The `render` binary, `bvh-bench --converge` and the tests all render through it, so the
//! choice between the CPU path ([`crate::render`]) and the GPU path ([`crate::gpu::trace`]) is
//! made here once, as pbrt-v4 chooses once between its CPU and wavefront integrators. It also
//! holds what differs between them beyond the kernel:
//! - the BVH: `lbvh` and `lbvh+prbvh` build on the GPU itself, `auto` times the device it
//!   renders on, and other builders build on the CPU;
//! - animation: both devices keep an instanced scene's two-level BVH (a tree per mesh, built
//!   once, under a top-level tree of instances) and update its top level in place each frame;
//!   the GPU then uploads the instances and the top level again, its meshes staying on the
//!   device;
//! - samples `auto` timed on the GPU become the first samples of the first frame.
//!
//! Without the `gpu` feature only [`Device::Cpu`] exists.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use crate::bvh::build::{Builder, UnknownBuilder};
use crate::bvh::dynamic::DynamicConfig;
use crate::bvh::dynamic::instances::TopLevelUpdate;
use crate::bvh::{TraceLayout, Tracing};
#[cfg(feature = "gpu")]
use crate::gpu::{GpuContext, GpuError, trace};
use crate::render::film::Film;
use crate::render::geometry::wants_instancing;
use crate::render::pass::{Pass, Progress};
use crate::render::refine::{RefineReport, Refiner};
use crate::render::region::{Rect, Region};
use crate::render::tiles::Rows;
use crate::render::{BuildReport, RenderScene, first_frame_time};
use crate::scene::{RenderSettings, Scene};

/// Where a render runs.
#[derive(Clone, Copy)]
pub enum Device {
    Cpu,
    #[cfg(feature = "gpu")]
    Gpu(&'static GpuContext),
}

impl Device {
    /// `cpu` or `gpu`.
    pub fn name(&self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            #[cfg(feature = "gpu")]
            Device::Gpu(_) => "gpu",
        }
    }

    /// The GPU adapter, as the user knows it (`None` on the CPU).
    pub fn adapter(&self) -> Option<String> {
        match self {
            Device::Cpu => None,
            #[cfg(feature = "gpu")]
            Device::Gpu(ctx) => Some(ctx.describe()),
        }
    }
}

/// What `--device` asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeviceChoice {
    Cpu,
    /// Any GPU adapter, software ones (lavapipe) included.
    Gpu,
    /// A hardware GPU where there is one, else the CPU (a software GPU is slower than the CPU
    /// path).
    Auto,
}

impl DeviceChoice {
    /// The device, and a line for the user saying what was chosen and why (`None` for the CPU
    /// when it was asked for).
    pub fn select(self) -> Result<(Device, Option<String>), DeviceError> {
        match self {
            DeviceChoice::Cpu => Ok((Device::Cpu, None)),
            #[cfg(feature = "gpu")]
            DeviceChoice::Gpu => {
                let ctx = GpuContext::shared().map_err(DeviceError::NoGpu)?;
                Ok((Device::Gpu(ctx), Some(format!("GPU: {}", ctx.describe()))))
            }
            #[cfg(not(feature = "gpu"))]
            DeviceChoice::Gpu => Err(DeviceError::NoGpuFeature),
            #[cfg(feature = "gpu")]
            DeviceChoice::Auto => match GpuContext::new(crate::gpu::AdapterPolicy::HardwareOnly) {
                // One context for the process's lifetime.
                Ok(ctx) => {
                    let ctx: &'static GpuContext = Box::leak(Box::new(ctx));
                    Ok((Device::Gpu(ctx), Some(format!("GPU: {}", ctx.describe()))))
                }
                Err(e) => Ok((Device::Cpu, Some(format!("no hardware GPU ({e}): rendering on the CPU")))),
            },
            #[cfg(not(feature = "gpu"))]
            DeviceChoice::Auto => Ok((Device::Cpu, None)),
        }
    }
}

/// A builder by name, or `auto`: the tree the render's estimated length repays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BuilderChoice {
    Fixed(Builder),
    Auto,
}

impl std::fmt::Display for BuilderChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BuilderChoice::Fixed(b) => write!(f, "{b}"),
            BuilderChoice::Auto => f.write_str("auto"),
        }
    }
}

impl std::str::FromStr for BuilderChoice {
    type Err = UnknownBuilder;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "auto" { Ok(BuilderChoice::Auto) } else { s.parse().map(BuilderChoice::Fixed) }
    }
}

impl BuilderChoice {
    /// The builder where none is named. On the CPU, `auto`: it renders at once on the LBVH and
    /// optimises while the render repays it ([`crate::render::refine`]); end to end it came
    /// within 10% of the fastest fixed builder on every scene and sample count measured but a
    /// 1M-triangle city, where binned SAH wins, and within 10% of the former default
    /// `lbvh+prbvh` nearly everywhere, many times faster at 1 spp (docs/benchmarks.md,
    /// "Builder auto"). On the GPU, `lbvh+prbvh` (built there) for a flat scene, and `auto`
    /// for a two-level one (animated or instanced), whose meshes, built once, get `lbvh+prbvh`
    /// as on the CPU. The GPU's `auto` for flat scenes now builds and optimises with the GPU's
    /// own LBVH and PRBVH on its own timings (`gpu::trace::build_auto`); it becomes the default
    /// once measured within that mark on a GPU (docs/design/builder-auto.md).
    pub fn default_for(device: Device, scene: &Scene) -> BuilderChoice {
        match device {
            Device::Cpu => {
                let _ = scene;
                BuilderChoice::Auto
            }
            #[cfg(feature = "gpu")]
            Device::Gpu(_) => {
                if wants_instancing(scene) {
                    BuilderChoice::Auto
                } else {
                    BuilderChoice::Fixed("lbvh+prbvh".parse().expect("a builder name"))
                }
            }
        }
    }
}

/// What can go wrong on a device.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[cfg(feature = "gpu")]
    #[error("--device gpu")]
    NoGpu(#[source] GpuError),
    #[cfg(not(feature = "gpu"))]
    #[error("--device gpu: this build of Arbor has no GPU backend (the `gpu` feature is off)")]
    NoGpuFeature,
    #[cfg(feature = "gpu")]
    #[error("building the BVH on the GPU")]
    Build(#[source] GpuError),
    #[cfg(feature = "gpu")]
    #[error("uploading the scene to the GPU")]
    Upload(#[source] GpuError),
    #[cfg(feature = "gpu")]
    #[error("compiling the GPU kernel")]
    Compile(#[source] GpuError),
    #[cfg(feature = "gpu")]
    #[error("rendering on the GPU")]
    Render(#[source] GpuError),
}

/// `auto`'s rule for an animation's per-frame top-level update on the CPU: its local PRBVH
/// runs while it repays itself, that is while the share of the top level's SAH it removed,
/// times the frame's render time, exceeds what it took (a generous bound on its gain: the
/// top level is only part of every ray's path). A frame that finds it does not pay skips it
/// for the next [`FramePrbvh::RETRY`] frames, then tries again: motion changes what it gains.
/// Frames where nothing moved are not judged, and a rebuild by the quality monitor while it is
/// skipped brings it back.
#[derive(Clone, Debug, Default)]
struct FramePrbvh {
    /// The last update's local PRBVH: (seconds, share of the SAH removed).
    last: Option<(f64, f64)>,
    /// Frames left to skip it.
    skip: u32,
}

impl FramePrbvh {
    const RETRY: u32 = 8;

    fn runs(&self) -> bool {
        self.skip == 0
    }

    fn updated(&mut self, stats: &crate::bvh::dynamic::UpdateStats) {
        self.last = None;
        if self.skip > 0 {
            // Without it the quality monitor rebuilt the tree, which costs more than the local
            // PRBVH it stood in for: run it again.
            self.skip = if stats.rebuilt { 0 } else { self.skip - 1 };
        } else if !stats.rebuilt && stats.moved > 0 {
            // A frame where nothing moved (the first, or a hold) says nothing of its worth.
            self.last = Some((stats.prbvh_seconds, stats.prbvh_sah_drop));
        }
    }

    fn rendered(&mut self, seconds: f64) {
        if let Some((spent, drop)) = self.last.take()
            && drop * seconds <= spent
        {
            self.skip = Self::RETRY;
        }
    }
}

/// A rendered frame.
pub struct RenderedFrame {
    pub film: Film,
    /// Rays traced, camera rays included.
    pub rays: u64,
    /// The render's seconds, those of samples carried over included.
    pub seconds: f64,
    /// Samples per pixel taken (fewer than asked where a time budget stopped the render).
    pub samples: u32,
    /// Of `seconds`, those of samples `auto` took while it timed the GPU, which its build's
    /// time counts too.
    pub timed_seconds: f64,
}

/// A scene made ready to render on one device: its BVH built (and uploaded), frame after frame.
pub struct Renderer {
    device: Device,
    render_scene: RenderScene,
    build: BuildReport,
    /// The scene time the geometry stands at.
    time: f32,
    /// A line about the GPU kernel, for the user.
    kernel_note: Option<String>,
    /// Seconds spent compiling GPU kernels while building (once per process and variant).
    compile_seconds: f64,
    /// `auto` on the CPU: the optimisation it carries out between passes.
    refiner: Option<Refiner>,
    /// Frames still to start after the one rendering, for `auto`'s estimate of the rest.
    frames_after: usize,
    /// `auto` on the CPU: whether an animated frame's top-level update runs its local PRBVH.
    frame_prbvh: Option<FramePrbvh>,
    #[cfg(feature = "gpu")]
    gpu: Option<GpuState>,
    /// The form the GPU traces.
    #[cfg(feature = "gpu")]
    gpu_form: trace::GpuForm,
}

#[cfg(feature = "gpu")]
struct GpuState {
    scene: trace::GpuScene,
    /// Samples `auto` timed, which the next render carries on.
    timed: Option<trace::PartialFilm>,
}

/// The tree forms a render traces: the CPU's (`render --trace` and `ARBOR_SIMD`) and the GPU's
/// (`render --trace`, else `wide8`: binary or wide8, [`trace::GpuForm`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Forms {
    pub cpu: Tracing,
    pub gpu: TraceLayout,
}

impl From<Tracing> for Forms {
    /// The CPU's form as given, the GPU's default.
    fn from(cpu: Tracing) -> Forms {
        Forms { cpu, gpu: TraceLayout::Wide8 }
    }
}

impl Renderer {
    /// Builds `scene` for rendering on `device`. `time` is the scene time of the first frame to
    /// be rendered ([`first_frame_time`] for a still): the GPU's scene is placed there, while
    /// the CPU builds at the scene's first frame and moves with [`Renderer::set_time`].
    /// `settings` and `frames` (the number of frames to come) tell `auto` how long the render
    /// will be; `settings.clamp` is applied. On the CPU the trees are traced as `tracing` says
    /// (`render --trace` and `ARBOR_SIMD`, read once by the caller); a GPU traces its own copy
    /// of the binary tree, and the CPU keeps that tree alone ([`Tracing::gpu`]).
    pub fn new(
        device: Device,
        scene: &Scene,
        builder: &BuilderChoice,
        forms: impl Into<Forms>,
        settings: &RenderSettings,
        frames: usize,
        time: f32,
    ) -> Result<Renderer, DeviceError> {
        let forms: Forms = forms.into();
        let tracing = forms.cpu;
        #[cfg(not(feature = "gpu"))]
        let _ = time; // the CPU builds at the scene's first frame and moves with `set_time`
        let mut refiner = None;
        let (mut render_scene, build) = match device {
            Device::Cpu => match builder {
                BuilderChoice::Fixed(b) => RenderScene::build(scene, b, tracing),
                BuilderChoice::Auto if wants_instancing(scene) => {
                    RenderScene::build(scene, &crate::render::auto::instanced_builder(), tracing)
                }
                BuilderChoice::Auto => {
                    let (rs, report, r) = Refiner::start(scene, tracing);
                    refiner = Some(r);
                    (rs, report)
                }
            },
            #[cfg(feature = "gpu")]
            Device::Gpu(ctx) => {
                let form = trace::GpuForm::of(forms.gpu).map_err(DeviceError::Upload)?;
                return Self::new_gpu(ctx, scene, builder, settings, (frames, time), form);
            }
        };
        render_scene.sample_clamp = settings.clamp;
        Ok(Renderer {
            device,
            render_scene,
            build,
            time: first_frame_time(scene),
            kernel_note: None,
            compile_seconds: 0.0,
            refiner,
            frames_after: frames,
            frame_prbvh: matches!(builder, BuilderChoice::Auto).then(FramePrbvh::default),
            #[cfg(feature = "gpu")]
            gpu: None,
            #[cfg(feature = "gpu")]
            gpu_form: trace::GpuForm::default(),
        })
    }

    #[cfg(feature = "gpu")]
    fn new_gpu(
        ctx: &'static GpuContext,
        scene: &Scene,
        builder: &BuilderChoice,
        settings: &RenderSettings,
        (frames, time): (usize, f32),
        form: trace::GpuForm,
    ) -> Result<Renderer, DeviceError> {
        let mut timed = None;
        let mut device_wide = None;
        let (render_scene, build) = if wants_instancing(scene) {
            // Two levels, as on the CPU: each mesh's tree built once (in object space), the
            // instances under a top-level tree the frames update in place.
            let mesh_builder = match builder {
                BuilderChoice::Fixed(b) => *b,
                BuilderChoice::Auto => crate::render::auto::instanced_builder(),
            };
            // `lbvh` and `lbvh+prbvh` (`auto`'s choice for meshes) build the large meshes on the
            // GPU, as they build a flat scene there.
            let name = mesh_builder.to_string();
            let (mut rs, report) = if name == "lbvh" || name == "lbvh+prbvh" {
                crate::gpu::build_instanced_for(ctx, scene, name == "lbvh+prbvh", &mesh_builder)
                    .map_err(DeviceError::Build)?
            } else {
                RenderScene::build(scene, &mesh_builder, Tracing::gpu())
            };
            if time != first_frame_time(scene) {
                rs.set_time(scene, time, &TopLevelUpdate::Dynamic(DynamicConfig::default()));
            }
            (rs, report)
        } else {
            // `lbvh` and `lbvh+prbvh` build on the GPU itself; other builders on the CPU.
            let on_gpu = match builder {
                BuilderChoice::Fixed(b) => {
                    let name = b.to_string();
                    (name == "lbvh" || name == "lbvh+prbvh").then_some(name == "lbvh+prbvh")
                }
                BuilderChoice::Auto => None,
            };
            let built_on_gpu = match on_gpu {
                Some(optimize) => {
                    crate::gpu::build_render_scene_for(ctx, scene, optimize, form).map_err(DeviceError::Build)?
                }
                None => None,
            };
            match (built_on_gpu, builder) {
                (Some((rs, report, wide)), _) => {
                    device_wide = wide;
                    (rs, report)
                }
                (None, BuilderChoice::Fixed(b)) => RenderScene::build(scene, b, Tracing::gpu()),
                (None, BuilderChoice::Auto) => {
                    let (rs, report, partial) = trace::build_auto(ctx, scene, settings, frames, form);
                    timed = partial;
                    (rs, report)
                }
            }
        };
        let mut renderer = Renderer {
            device: Device::Gpu(ctx),
            render_scene,
            build,
            time,
            kernel_note: None,
            compile_seconds: 0.0,
            refiner: None,
            frames_after: frames,
            frame_prbvh: None,
            gpu: None,
            gpu_form: form,
        };
        renderer.upload(settings.clamp, timed, device_wide)?;
        Ok(renderer)
    }

    /// Uploads the scene as it stands (with the wide tree the GPU made of it, if any) and
    /// compiles its kernel variant.
    #[cfg(feature = "gpu")]
    fn upload(
        &mut self,
        clamp: Option<f32>,
        timed: Option<trace::PartialFilm>,
        wide: Option<crate::gpu::wide::DeviceWide>,
    ) -> Result<(), DeviceError> {
        let Device::Gpu(ctx) = self.device else { return Ok(()) };
        self.render_scene.sample_clamp = clamp;
        let scene =
            trace::GpuScene::upload_with(ctx, &self.render_scene, self.gpu_form, wide).map_err(DeviceError::Upload)?;
        let t = Instant::now();
        trace::compile(ctx, &scene).map_err(DeviceError::Compile)?;
        self.compile_seconds += t.elapsed().as_secs_f64();
        if self.kernel_note.is_none() {
            self.kernel_note = Some(format!(
                "GPU kernel {} ready in {:.2} s, {} BVH of depth {}",
                scene.features.key(),
                t.elapsed().as_secs_f64(),
                scene.form.name(),
                scene.depth
            ));
        }
        self.gpu = Some(GpuState { scene, timed });
        Ok(())
    }

    pub fn device(&self) -> Device {
        self.device
    }

    /// What building the scene's BVH cost and chose.
    pub fn build_report(&self) -> &BuildReport {
        &self.build
    }

    /// What `auto` did while a CPU render ran (`None` for other builders and devices).
    pub fn refine_report(&self) -> Option<&RefineReport> {
        self.refiner.as_ref().map(Refiner::report)
    }

    /// The scene as the CPU's integrator reads it (on the GPU, what was uploaded).
    pub fn render_scene(&self) -> &RenderScene {
        &self.render_scene
    }

    /// The tree form traced: the CPU's layout (`binary`, `wide4`, `wide8`), or the GPU's
    /// (`binary`, `wide8`).
    pub fn trace_form(&self) -> &'static str {
        match self.device {
            Device::Cpu => self.build.tracing.layout.name(),
            #[cfg(feature = "gpu")]
            Device::Gpu(_) => self.gpu_form.name(),
        }
    }

    /// On the GPU, a line on the kernel variant compiled for the scene (once, at the build).
    pub fn kernel_note(&self) -> Option<&str> {
        self.kernel_note.as_deref()
    }

    /// Seconds [`Renderer::new`] spent compiling GPU kernels, which a build's time may leave
    /// out: the pipelines are cached for the rest of the process.
    pub fn compile_seconds(&self) -> f64 {
        self.compile_seconds
    }

    /// Moves an animated scene to scene time `time` and returns what updating its BVH took, in
    /// milliseconds; `None` where nothing was updated (a static scene, or the GPU's scene
    /// already at `time`). Both devices update the two-level BVH's top level in place (delete,
    /// clean up, reinsert); the GPU then uploads the instances and the top level (counted).
    pub fn set_time(&mut self, scene: &Scene, time: f32) -> Result<Option<f64>, DeviceError> {
        match self.device {
            Device::Cpu => {
                let t = Instant::now();
                let mut config = DynamicConfig::default();
                if self.frame_prbvh.as_ref().is_some_and(|f| !f.runs()) {
                    config.prbvh_rounds = 0;
                }
                let stats = self.render_scene.set_time(scene, time, &TopLevelUpdate::Dynamic(config));
                if let (Some(f), Some(stats)) = (self.frame_prbvh.as_mut(), &stats) {
                    f.updated(stats);
                }
                self.time = time;
                Ok(stats.map(|_| t.elapsed().as_secs_f64() * 1e3))
            }
            #[cfg(feature = "gpu")]
            Device::Gpu(ctx) => {
                if !wants_instancing(scene) || time == self.time {
                    return Ok(None);
                }
                let t = Instant::now();
                // The top level updated in place on the host as on the CPU (delete, clean,
                // reinsert), then the instances, the top-level tree and the lights uploaded:
                // the meshes' trees stay on the device.
                let stats = self.render_scene.set_time(scene, time, &TopLevelUpdate::Dynamic(DynamicConfig::default()));
                self.time = time;
                if stats.is_none() {
                    return Ok(None);
                }
                if let Some(gpu) = self.gpu.as_mut() {
                    gpu.scene.update_instances(ctx, &self.render_scene).map_err(DeviceError::Upload)?;
                    gpu.timed = None;
                }
                // The whole update: the top level and the upload.
                Ok(Some(t.elapsed().as_secs_f64() * 1e3))
            }
        }
    }

    /// Renders samples `0..settings.spp` of every pixel (fewer where `settings.time` runs out:
    /// the render stops after the pass that crosses it) with `settings.seed` and
    /// `settings.max_depth`. `progress` hears of every row (CPU) or pass (GPU) done.
    pub fn render(
        &mut self,
        settings: &RenderSettings,
        progress: &(dyn Fn(Progress) + Sync),
    ) -> Result<RenderedFrame, DeviceError> {
        let region = self.whole(settings.spp);
        self.begin_frame();
        self.render_region(Pass::new(settings, region).with_progress(progress))
    }

    /// Says a new frame starts (for `auto`'s estimate of the frames to come); [`Renderer::render`]
    /// says it itself, callers of [`Renderer::render_region`] once per frame.
    pub fn begin_frame(&mut self) {
        self.frames_after = self.frames_after.saturating_sub(1);
    }

    /// [`Renderer::render`], carrying on from `frame`, a render of this scene with the same
    /// seed and depth, up to `settings.spp` samples: the film gains samples
    /// `frame.samples..settings.spp`, and its image is the one an uninterrupted render gives.
    pub fn render_more(
        &mut self,
        frame: RenderedFrame,
        settings: &RenderSettings,
        progress: &(dyn Fn(Progress) + Sync),
    ) -> Result<RenderedFrame, DeviceError> {
        let region = self.whole(settings.spp);
        self.render_region(Pass::new(settings, region).carrying(Some(frame)).with_progress(progress))
    }

    /// The whole image, samples `0..spp`.
    fn whole(&self, spp: u32) -> Region {
        Region { rect: Rect::full(self.render_scene.width, self.render_scene.height), samples: 0..spp }
    }

    /// Renders `pass.region`: the samples `region.samples` of each pixel of `region.rect`, into a
    /// film of the rectangle's size (its pixel (0, 0) is the image's `(rect.x0, rect.y0)`), with
    /// the seed, path depth and time budget of `pass.settings` (`settings.spp` is not read).
    /// `pass.carried`, where given, holds the region's first `carried.samples` samples (a
    /// checkpoint, or an earlier call), and the render carries on from there. `pass.pause` is
    /// asked after each pass with the samples per pixel taken so far (of the region's); when it
    /// says yes, the render returns there, to be carried on later. The image never depends on
    /// where passes, pauses or devices' passes fall: the film's sums are exact
    /// ([`crate::render::film`]).
    pub fn render_region(&mut self, mut pass: Pass<'_, RenderedFrame>) -> Result<RenderedFrame, DeviceError> {
        let region = &pass.region;
        let (w, h) = (self.render_scene.width, self.render_scene.height);
        assert!(
            region.rect.fits(w, h) && region.samples.start <= region.samples.end,
            "region {:?} outside a {w}x{h} image",
            region
        );
        let frame = pass.carried.take().unwrap_or_else(|| RenderedFrame {
            film: Film::new(region.rect.width(), region.rect.height()),
            rays: 0,
            seconds: 0.0,
            samples: 0,
            timed_seconds: 0.0,
        });
        match self.device {
            Device::Cpu => Ok(self.render_cpu(frame, &pass)),
            #[cfg(feature = "gpu")]
            Device::Gpu(ctx) => self.render_gpu(ctx, frame, &pass),
        }
    }

    fn render_cpu(&mut self, frame: RenderedFrame, pass: &Pass<'_, RenderedFrame>) -> RenderedFrame {
        let Pass { settings: s, ref region, progress, pause, abandon, .. } = *pass;
        let RenderedFrame { mut film, rays: rays_before, seconds: seconds_before, samples: taken, timed_seconds } =
            frame;
        let (first, end) = (region.samples.start, region.samples.end);
        let origin = (region.rect.x0, region.rect.y0);
        let mut done = first + taken;
        let height = u64::from(region.rect.height());
        let total = u64::from(end - first) * height;
        let units = AtomicU64::new(u64::from(taken) * height);
        let rays = AtomicU64::new(rays_before);
        let start = Instant::now();
        // Passes of a few samples each, so that a time budget can stop between passes and
        // progress is heard of even when one pixel's samples take long (a row reports when it
        // has done the pass). While `auto` still decides, a pass is a slice of one sample: every
        // `slices`-th row, spread over the image so that it costs a share of what the whole
        // sample does, so the decisions come within the first sample, even in a 1-spp render.
        // Up to 16 slices, each of at least 16 rows per thread: with 4 rows per thread, 16
        // threads finished a slice at the pace of its slowest rows, and the estimate came out
        // 1.4 to 1.7 times the render. The image depends only on the samples taken, not on
        // where passes fall or on the tree, as long as each pixel gets its samples in order: a
        // sample begun in slices is finished before the next.
        let threads = rayon::current_num_threads() as u32;
        let slices = (region.rect.height() / (16 * threads).max(1)).clamp(1, 16);
        let pass_spp = if s.time.is_some() { 4 } else { 16 }.min((end - first).max(1));
        // Slices of sample `done` rendered so far: the rows `y % slices < slice`.
        let mut slice = 0;
        // Every row of the samples `samples`; a pass narrows the rows and names its listener.
        let rows = |samples| Rows {
            origin,
            seed: s.seed,
            max_depth: s.max_depth,
            samples,
            filter: &|_| true,
            progress: &|_| {},
            abandon,
        };
        // Passes render into `fresh`, added to `film` at each whole sample count (every pixel
        // holding the same samples): an abandoned pass (`abandon`, a signal) is dropped with
        // it, and the film returned is whole, of `whole` samples.
        let mut fresh = Film::new(film.width(), film.height());
        let mut whole = done;
        // The rays of the samples in `film`: an abandoned pass's are not counted.
        let mut rays_at_whole = rays_before;
        while done < end {
            let deciding = slice < slices && self.refiner.as_ref().is_some_and(Refiner::is_active);
            let pass_start = Instant::now();
            let (rays, units) = (&rays, &units);
            let report = |n: u32| {
                move |r: u64| {
                    let rays = rays.fetch_add(r, Ordering::Relaxed) + r;
                    let done = units.fetch_add(u64::from(n), Ordering::Relaxed) + u64::from(n);
                    progress(Progress { done, total, rays });
                }
            };
            // The share of a sample this pass renders.
            let share = if deciding || slice > 0 {
                // While deciding, the next slice of sample `done`; after, the rest of it.
                let k = slice;
                let filter = move |y: u32| if deciding { y % slices == k } else { y % slices >= k };
                let rows = Rows { filter: &filter, progress: &report(1), ..rows(done..done + 1) };
                self.render_scene.render_rows(&mut fresh, &rows);
                slice = if deciding { k + 1 } else { slices };
                f64::from(slice - k) / f64::from(slices)
            } else {
                let n = pass_spp.min(end - done);
                let rows = Rows { progress: &report(n), ..rows(done..done + n) };
                self.render_scene.render_rows(&mut fresh, &rows);
                done += n;
                f64::from(n)
            };
            if abandon() {
                done = whole;
                rays.store(rays_at_whole, Ordering::Relaxed);
                break;
            }
            if slice == slices {
                (slice, done) = (0, done + 1);
            }
            if slice == 0 {
                film.take_samples_from(&mut fresh);
                whole = done;
                rays_at_whole = rays.load(Ordering::Relaxed);
            }
            let elapsed = seconds_before + start.elapsed().as_secs_f64();
            if slice == 0 && (s.time.is_some_and(|t| elapsed >= t) || (done < end && pause(done - first))) {
                break;
            }
            if deciding {
                let taken = f64::from(done - first) + f64::from(slice) / f64::from(slices);
                let per_frame = f64::from(end - first);
                let samples_left = per_frame - taken + self.frames_after as f64 * per_frame;
                if samples_left > 0.0 {
                    // A time budget is per frame.
                    let budget_left = s.time.map(|t| t - elapsed + self.frames_after as f64 * t);
                    let rest = |per_sample: f64| {
                        budget_left.map_or(per_sample * samples_left, |b| b.min(per_sample * samples_left))
                    };
                    let pass_seconds = pass_start.elapsed().as_secs_f64();
                    let refiner = self.refiner.as_mut().expect("deciding");
                    refiner.after_pass(&mut self.render_scene, (pass_seconds, share), taken, &rest, abandon);
                }
            }
        }
        let seconds = seconds_before + start.elapsed().as_secs_f64();
        if done == end {
            if let Some(f) = self.frame_prbvh.as_mut() {
                f.rendered(seconds);
            }
            // The last frame is over: what `auto` kept to decide with can go.
            if let Some(r) = self.refiner.as_mut().filter(|r| r.is_active() && self.frames_after == 0) {
                r.finish();
            }
        }
        RenderedFrame { film, rays: rays.into_inner(), seconds, samples: done - first, timed_seconds }
    }

    #[cfg(feature = "gpu")]
    fn render_gpu(
        &mut self,
        ctx: &GpuContext,
        frame: RenderedFrame,
        pass: &Pass<'_, RenderedFrame>,
    ) -> Result<RenderedFrame, DeviceError> {
        let Pass { settings: s, ref region, progress, pause, abandon, .. } = *pass;
        let gpu = self.gpu.as_mut().expect("a GPU renderer holds its uploaded scene");
        let RenderedFrame { mut film, rays: rays_before, seconds: seconds_before, samples: taken, timed_seconds } =
            frame;
        let first = region.samples.start;
        // The passes `auto` timed are the whole image's first samples: they start a render of
        // just that, and are dropped by any other.
        let full = region.rect == Rect::full(self.render_scene.width, self.render_scene.height);
        let timed = gpu.timed.take().filter(|_| full && first + taken == 0);
        let height = u64::from(region.rect.height());
        let total = u64::from(region.samples.len() as u32) * height;
        let start = Instant::now();
        // The device renders the samples not yet taken, within what the samples carried left of
        // the budget; its progress and pauses count from there, the region's from its start.
        let settings = RenderSettings { time: s.time.map(|t| t - seconds_before), ..*s };
        let device_progress =
            |p: Progress| progress(Progress { done: p.done + u64::from(taken) * height, total, rays: 0 });
        let device_pause = |n: u32| pause(n + taken);
        let rest = Region { rect: region.rect, samples: first + taken..region.samples.end };
        let device_pass = Pass::new(&settings, rest)
            .carrying(timed)
            .with_progress(&device_progress)
            .with_pause(&device_pause)
            .with_abandon(abandon);
        let out = trace::render_from(ctx, &gpu.scene, device_pass).map_err(DeviceError::Render)?;
        // The device's sums are exact, as the host's: adding them to the samples carried gives
        // the film of an uninterrupted render.
        film.merge(&out.film);
        let seconds = seconds_before + out.carried.1 + start.elapsed().as_secs_f64();
        Ok(RenderedFrame {
            film,
            rays: rays_before + out.rays,
            seconds,
            samples: out.end - first,
            timed_seconds: timed_seconds + out.carried.1,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::dynamic::UpdateStats;

    fn update(prbvh_seconds: f64, prbvh_sah_drop: f64) -> UpdateStats {
        UpdateStats { moved: 3, prbvh_seconds, prbvh_sah_drop, ..Default::default() }
    }

    /// The local PRBVH of an animation's frames runs while the SAH share it removes, times the
    /// frame's render, exceeds its time; once it does not, the next `RETRY` frames skip it and
    /// the one after tries again.
    #[test]
    fn frame_prbvh_runs_while_it_repays_itself() {
        let mut f = FramePrbvh::default();
        assert!(f.runs());
        // 1% of a 1 s render is 10 ms, more than the 1 ms it took: keep it.
        f.updated(&update(1e-3, 0.01));
        f.rendered(1.0);
        assert!(f.runs());
        // 1% of a 50 ms render is 0.5 ms, less than 1 ms: skip it.
        f.updated(&update(1e-3, 0.01));
        f.rendered(0.05);
        for _ in 0..FramePrbvh::RETRY {
            assert!(!f.runs());
            f.updated(&update(0.0, 0.0));
            f.rendered(0.05);
        }
        assert!(f.runs());
        // A frame the monitor rebuilt, or where nothing moved, says nothing about it.
        f.updated(&UpdateStats { rebuilt: true, ..update(1.0, 0.0) });
        f.rendered(0.05);
        assert!(f.runs());
        f.updated(&UpdateStats { moved: 0, ..update(1e-6, 0.0) });
        f.rendered(0.05);
        assert!(f.runs());
        // Skipped, until the monitor has to rebuild the tree: then it runs again.
        f.updated(&update(1e-3, 0.01));
        f.rendered(0.05);
        assert!(!f.runs());
        f.updated(&UpdateStats { rebuilt: true, ..update(0.0, 0.0) });
        assert!(f.runs());
    }
}
