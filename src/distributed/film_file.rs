//! Partial films: a piece of a render (a rectangle of the image, a range of sample indices, a
//! frame) saved with everything an exact merge needs, and the merge itself (`render --merge`).
//!
//! A piece is an OpenEXR file that any EXR viewer opens: its data window is the rectangle, placed
//! in a display window of the whole image, and its `R`, `G`, `B` channels (f32) are the
//! rectangle's mean so far. Beside them it keeps, per pixel, the film's exact sums
//! ([`crate::render::film`]) in 32-bit unsigned channels:
//! - `arbor.sum.{R,G,B}.{0,1,2,3}`: the 128-bit fixed-point sum, least significant limb first;
//! - `arbor.sumsq.{R,G,B}.{lo,hi}`: the f64 sum of squares, as its bits;
//! - `arbor.count.{lo,hi}` and `arbor.dropped.{lo,hi}`: samples added and dropped (u64).
//!
//! Header attributes (text) say what the piece is ([`PieceInfo`]): `arbor.format`,
//! `arbor.scene_hash` ([`crate::scene::Scene::content_hash`]), `arbor.seed`, `arbor.max_depth`,
//! `arbor.clamp`, `arbor.resolution`, `arbor.frame`, `arbor.device`, `arbor.rect`,
//! `arbor.samples` (asked), `arbor.samples_done`, `arbor.rays`, `arbor.seconds`.
//!
//! `arbor.integrity` is `sha256:` and the SHA-256 ([`integrity`]) of the other `arbor.*`
//! attributes and of every channel's samples, as decoded. A reader recomputes it from what it
//! decoded and refuses a piece that differs: a sum altered on disk or in transfer (even one
//! recompressed into a well-formed file) is caught before it changes an image. It detects
//! corruption and mix-ups, not forgery: anyone can recompute it.
//!
//! The merge ([`merge`]) refuses pieces that do not belong together, naming the first that does
//! not, and adds the rest: integer sums, so the merged image is a single render's bit for bit,
//! in any order of the pieces. EXR keeps no f64 or 128-bit channel, hence the limbs; ZIP
//! compression makes the mostly-zero high limbs cost little.

use std::ops::Range;
use std::path::{Path, PathBuf};

use exr::prelude::{
    AnyChannel, AnyChannels, AttributeValue, Encoding, FlatSamples, Image as ExrImage, IntegerBounds, Layer,
    LayerAttributes, ReadChannels, ReadLayers, SmallVec, Text, Vec2, WritableImage, read,
};

use crate::atomic_file::{AtomicWriteError, write_atomic};
use crate::render::film::{FRACTION_BITS, Film, PixelAccum, SAMPLE_LIMIT_LOG2};
use crate::render::region::Rect;

/// `arbor.format` of the files this version writes and reads.
/// `arbor.format` of the files this version writes and reads. Version 2 added
/// `arbor.integrity`; version 1 pieces are refused with a message naming both.
pub const FORMAT: &str = "arbor partial film 2";

/// The header attribute that holds a piece's [`integrity`] digest.
pub const INTEGRITY: &str = "arbor.integrity";

/// What a piece is: which render it belongs to, and which part of it it holds.
#[derive(Clone, Debug, PartialEq)]
pub struct PieceInfo {
    /// [`crate::scene::Scene::content_hash`].
    pub scene_hash: String,
    pub seed: u64,
    pub max_depth: u32,
    /// The firefly clamp, if any.
    pub clamp: Option<f32>,
    /// The whole image's size.
    pub width: u32,
    pub height: u32,
    /// The frame of an animation, `None` for a still.
    pub frame: Option<u32>,
    /// `cpu` or `gpu`: the devices draw different random numbers, so their pieces do not make
    /// one render.
    pub device: String,
    pub rect: Rect,
    /// The sample indices asked for.
    pub samples: Range<u32>,
    /// The piece holds samples `samples.start..done`; it is complete when `done == samples.end`.
    pub done: u32,
    /// Rays traced and seconds spent rendering so far.
    pub rays: u64,
    pub seconds: f64,
}

impl PieceInfo {
    pub fn is_complete(&self) -> bool {
        self.done == self.samples.end
    }

    /// The sample indices held.
    pub fn held(&self) -> Range<u32> {
        self.samples.start..self.done
    }

    /// The first thing, if any, that keeps `other` from being part of the same render as this:
    /// `(what, this one's, the other's)`.
    pub fn differs_from(&self, other: &PieceInfo) -> Option<(&'static str, String, String)> {
        let clamp = |c: Option<f32>| c.map_or_else(|| "off".to_owned(), |c| c.to_string());
        let frame = |f: Option<u32>| f.map_or_else(|| "still".to_owned(), |f| f.to_string());
        [
            ("scene hash", self.scene_hash.clone(), other.scene_hash.clone()),
            ("seed", self.seed.to_string(), other.seed.to_string()),
            ("max depth", self.max_depth.to_string(), other.max_depth.to_string()),
            ("clamp", clamp(self.clamp), clamp(other.clamp)),
            ("resolution", format!("{}x{}", self.width, self.height), format!("{}x{}", other.width, other.height)),
            ("frame", frame(self.frame), frame(other.frame)),
            ("device", self.device.clone(), other.device.clone()),
        ]
        .into_iter()
        .find(|(_, a, b)| a != b)
    }

    /// Whether `other` is this very piece (the same render, rectangle and samples asked), at
    /// whatever progress: what `--resume` carries on.
    pub fn same_piece(&self, other: &PieceInfo) -> bool {
        self.differs_from(other).is_none() && self.rect == other.rect && self.samples == other.samples
    }
}

/// A piece: what it is, and its film (of the rectangle's size).
#[derive(Clone, Debug, PartialEq)]
pub struct FilmPiece {
    pub info: PieceInfo,
    pub film: Film,
}

/// What can go wrong reading or merging pieces. Each names the file at fault.
#[derive(Debug, thiserror::Error)]
pub enum PieceError {
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not a readable EXR: {source}", path.display())]
    Exr {
        path: PathBuf,
        #[source]
        source: exr::error::Error,
    },
    #[error("{}: not an Arbor partial film: {why}", path.display())]
    Foreign { path: PathBuf, why: String },
    #[error("{}: {what} is {theirs}, but {} has {ours}: not a piece of the same render", path.display(), first.display())]
    Mismatch { path: PathBuf, first: PathBuf, what: &'static str, ours: String, theirs: String },
    #[error("{}: unfinished: it holds samples {}..{} of {}..{}; finish it with `render ... --resume`", path.display(), held.start, held.end, asked.start, asked.end)]
    Unfinished { path: PathBuf, held: Range<u32>, asked: Range<u32> },
    #[error("{} and {} overlap: both hold samples {}..{} of pixels {}", a.display(), b.display(), samples.start, samples.end, rect)]
    Overlap { a: PathBuf, b: PathBuf, samples: Range<u32>, rect: Rect },
    #[error("a piece is missing: samples {}..{} are held for {covered} of the image's {total} pixels (none holds pixel ({}, {}))", samples.start, samples.end, pixel.0, pixel.1)]
    Missing { samples: Range<u32>, covered: u64, total: u64, pixel: (u32, u32) },
    /// The piece's header or pixels are not what it was written with.
    #[error("{}: damaged or altered: its contents do not match its {INTEGRITY} (stated {stated}, computed {actual}); render this piece again", path.display())]
    Integrity { path: PathBuf, stated: String, actual: String },
    #[error("no pieces to merge")]
    Empty,
    #[error(transparent)]
    Memory(#[from] crate::memory::OutOfMemory),
}

/// Writes the piece `info` describes, its film `film`, to `path` (atomically: see
/// [`crate::atomic_file`]).
pub fn write_piece(path: &Path, info: &PieceInfo, film: &Film) -> Result<(), crate::image_io::ImageError> {
    write_piece_with(path, info, film, Encoding::SMALL_LOSSLESS)
}

/// [`write_piece`] when time matters more than bytes (a signal's grace period runs): run-length
/// compression, which encodes in about half ZIP's time and takes about four times its bytes.
/// Readers do not care which.
pub fn write_piece_quickly(path: &Path, info: &PieceInfo, film: &Film) -> Result<(), crate::image_io::ImageError> {
    write_piece_with(path, info, film, Encoding::FAST_LOSSLESS)
}

fn write_piece_with(
    path: &Path,
    info: &PieceInfo,
    film: &Film,
    encoding: Encoding,
) -> Result<(), crate::image_io::ImageError> {
    use crate::image_io::ImageError;
    let encoded = encode(info, film, encoding).map_err(|source| ImageError::Exr {
        path: path.to_path_buf(),
        what: "encode",
        source,
    })?;
    write_atomic(path, |out| std::io::Write::write_all(out, &encoded)).map_err(|e| match e {
        AtomicWriteError::Io { what, source } => ImageError::Io { path: path.to_path_buf(), what, source },
        AtomicWriteError::Write(source) => ImageError::Io { path: path.to_path_buf(), what: "cannot write", source },
    })
}

fn encode(info: &PieceInfo, film: &Film, encoding: Encoding) -> Result<Vec<u8>, exr::error::Error> {
    let px = film.pixels();
    let u32s = |f: &dyn Fn(&PixelAccum) -> u32| FlatSamples::U32(px.iter().map(f).collect());
    let mut channels: Vec<AnyChannel<FlatSamples>> = Vec::new();
    let means: Vec<[f32; 3]> = px.iter().map(PixelAccum::mean).collect();
    for (c, name) in ["R", "G", "B"].into_iter().enumerate() {
        channels.push(AnyChannel::new(name, FlatSamples::F32(means.iter().map(|m| m[c]).collect())));
        for limb in 0..4 {
            let data = u32s(&|p| (p.sum[c] >> (32 * limb)) as u32);
            channels.push(AnyChannel::new(format!("arbor.sum.{name}.{limb}").as_str(), data));
        }
        for (half, shift) in [("lo", 0), ("hi", 32)] {
            let data = u32s(&|p| (p.sum_sq[c].to_bits() >> shift) as u32);
            channels.push(AnyChannel::new(format!("arbor.sumsq.{name}.{half}").as_str(), data));
        }
    }
    for (half, shift) in [("lo", 0), ("hi", 32)] {
        channels.push(AnyChannel::new(format!("arbor.count.{half}").as_str(), u32s(&|p| (p.count >> shift) as u32)));
        let dropped = u32s(&|p| (p.non_finite >> shift) as u32);
        channels.push(AnyChannel::new(format!("arbor.dropped.{half}").as_str(), dropped));
    }
    let mut attributes =
        LayerAttributes { layer_position: Vec2(info.rect.x0 as i32, info.rect.y0 as i32), ..Default::default() };
    let header: Vec<(String, String)> = attributes_of(info).into_iter().map(|(k, v)| (k.to_owned(), v)).collect();
    let channels = AnyChannels::sort(SmallVec::from_vec(channels));
    let digest = integrity(&header, &channels.list);
    for (key, value) in header.iter().chain([&(INTEGRITY.to_owned(), digest)]) {
        attributes.other.insert(Text::from(key.as_str()), AttributeValue::Text(Text::from(value.as_str())));
    }
    let size = (info.rect.width() as usize, info.rect.height() as usize);
    let layer = Layer::new(size, attributes, encoding, channels);
    let mut image = ExrImage::from_layer(layer);
    image.attributes.display_window = IntegerBounds::new(Vec2(0, 0), Vec2(info.width as usize, info.height as usize));
    // In memory: the encoder seeks back to write its offset tables (see `image_io`).
    let mut encoded = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut encoded)?;
    Ok(encoded.into_inner())
}

fn attributes_of(info: &PieceInfo) -> Vec<(&'static str, String)> {
    vec![
        ("arbor.format", FORMAT.to_owned()),
        ("arbor.scene_hash", info.scene_hash.clone()),
        ("arbor.seed", info.seed.to_string()),
        ("arbor.max_depth", info.max_depth.to_string()),
        ("arbor.clamp", info.clamp.map_or_else(|| "off".to_owned(), |c| format!("{c:?}"))),
        ("arbor.resolution", format!("{}x{}", info.width, info.height)),
        ("arbor.frame", info.frame.map_or_else(|| "still".to_owned(), |f| f.to_string())),
        ("arbor.device", info.device.clone()),
        ("arbor.rect", info.rect.to_string()),
        ("arbor.samples", format!("{}..{}", info.samples.start, info.samples.end)),
        ("arbor.samples_done", format!("{}..{}", info.samples.start, info.done)),
        ("arbor.rays", info.rays.to_string()),
        ("arbor.seconds", format!("{:?}", info.seconds)),
    ]
}

/// `sha256:` and the hex SHA-256 of a piece's `arbor.*` header attributes but
/// [`INTEGRITY`] (`header`, in any order: they are sorted by key) and its `channels` (sorted by
/// name, as EXR stores them): each attribute's key and value, each channel's name, sample type
/// and samples (little-endian), every string and list preceded by its length.
pub fn integrity(header: &[(String, String)], channels: &[AnyChannel<FlatSamples>]) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    fn field(h: &mut Sha256, b: &[u8]) {
        h.update((b.len() as u64).to_le_bytes());
        h.update(b);
    }
    field(&mut h, b"arbor partial film integrity 1");
    let mut sorted: Vec<&(String, String)> = header.iter().filter(|(k, _)| k != INTEGRITY).collect();
    sorted.sort();
    for (key, value) in sorted {
        field(&mut h, key.as_bytes());
        field(&mut h, value.as_bytes());
    }
    for c in channels {
        field(&mut h, c.name.to_string().as_bytes());
        match &c.sample_data {
            FlatSamples::F16(v) => {
                field(&mut h, b"f16");
                let data: Vec<u8> = v.iter().flat_map(|x| x.to_bits().to_le_bytes()).collect();
                field(&mut h, &data);
            }
            FlatSamples::F32(v) => {
                field(&mut h, b"f32");
                hash_words(&mut h, bytemuck::cast_slice(v));
            }
            FlatSamples::U32(v) => {
                field(&mut h, b"u32");
                hash_words(&mut h, v);
            }
        }
    }
    let digest = h.finalize();
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    format!("sha256:{hex}")
}

/// Hashes `words` as [`integrity`]'s field of their little-endian bytes: in place on a
/// little-endian machine (a piece's channels are about 100 bytes a pixel, and a copy would cost
/// as much as the hash), through a copy elsewhere.
fn hash_words(h: &mut sha2::Sha256, words: &[u32]) {
    use sha2::Digest;
    h.update((words.len() as u64 * 4).to_le_bytes());
    if cfg!(target_endian = "little") {
        h.update(bytemuck::cast_slice::<u32, u8>(words));
    } else {
        let data: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        h.update(&data);
    }
}

/// What `path`'s header says it is, without reading its pixels: `Ok(None)` where it is an EXR
/// but not a partial film (an image), an error where it cannot be read or is not an EXR.
pub fn read_info(path: &Path) -> Result<Option<PieceInfo>, PieceError> {
    // Opening a FIFO would wait for a writer, and a folder or a device is no piece either.
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => return Err(foreign(path, "it is a folder")),
        Ok(m) if !m.is_file() => return Err(foreign(path, "it is not a regular file")),
        Err(source) => return Err(PieceError::Io { path: path.to_path_buf(), source }),
        Ok(_) => {}
    }
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| exr_error(path, e))?;
    let header = meta.headers.first().ok_or_else(|| foreign(path, "the file has no layer"))?;
    let attrs = |key: &str| -> Option<String> {
        let key = Text::from(key);
        let value = header.own_attributes.other.get(&key).or_else(|| header.shared_attributes.other.get(&key))?;
        match value {
            AttributeValue::Text(t) => Some(t.to_string()),
            _ => None,
        }
    };
    if attrs("arbor.format").is_none() {
        return Ok(None);
    }
    parse_info(path, &attrs).map(Some)
}

fn exr_error(path: &Path, e: exr::error::Error) -> PieceError {
    match e {
        exr::error::Error::Io(source) => PieceError::Io { path: path.to_path_buf(), source },
        source => PieceError::Exr { path: path.to_path_buf(), source },
    }
}

fn foreign(path: &Path, why: impl Into<String>) -> PieceError {
    PieceError::Foreign { path: path.to_path_buf(), why: why.into() }
}

fn parse_info(path: &Path, attrs: &dyn Fn(&str) -> Option<String>) -> Result<PieceInfo, PieceError> {
    let get = |key: &str| attrs(key).ok_or_else(|| foreign(path, format!("no {key} attribute")));
    let bad = |key: &str, value: &str| foreign(path, format!("{key} {value:?} is malformed"));
    let format = get("arbor.format")?;
    if format != FORMAT {
        return Err(foreign(path, format!("arbor.format is {format:?}; this version reads {FORMAT:?}")));
    }
    let number = |key: &str| -> Result<u64, PieceError> {
        let v = get(key)?;
        v.parse().map_err(|_| bad(key, &v))
    };
    let u32_of = |key: &str| -> Result<u32, PieceError> {
        let v = get(key)?;
        v.parse().map_err(|_| bad(key, &v))
    };
    let range = |key: &str| -> Result<Range<u32>, PieceError> {
        let v = get(key)?;
        let (a, b) = v.split_once("..").ok_or_else(|| bad(key, &v))?;
        let (a, b): (u32, u32) = (a.parse().map_err(|_| bad(key, &v))?, b.parse().map_err(|_| bad(key, &v))?);
        if b < a {
            return Err(bad(key, &v));
        }
        Ok(a..b)
    };
    let clamp = match get("arbor.clamp")?.as_str() {
        "off" => None,
        v => Some(v.parse::<f32>().ok().filter(|c| c.is_finite() && *c > 0.0).ok_or_else(|| bad("arbor.clamp", v))?),
    };
    let resolution = get("arbor.resolution")?;
    let (width, height) = resolution
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .ok_or_else(|| bad("arbor.resolution", &resolution))?;
    let frame = match get("arbor.frame")?.as_str() {
        "still" => None,
        _ => Some(u32_of("arbor.frame")?),
    };
    let rect_text = get("arbor.rect")?;
    let rect = parse_rect(&rect_text).filter(|r| r.fits(width, height)).ok_or_else(|| {
        foreign(path, format!("arbor.rect {rect_text:?} is not a rectangle of the {width}x{height} image"))
    })?;
    let samples = range("arbor.samples")?;
    let done = range("arbor.samples_done")?;
    if done.start != samples.start || done.end > samples.end {
        return Err(foreign(path, format!("arbor.samples_done {done:?} is not part of arbor.samples {samples:?}")));
    }
    let seconds_text = get("arbor.seconds")?;
    let seconds = seconds_text.parse::<f64>().ok().filter(|s| s.is_finite() && *s >= 0.0);
    Ok(PieceInfo {
        scene_hash: get("arbor.scene_hash")?,
        seed: number("arbor.seed")?,
        max_depth: u32_of("arbor.max_depth")?,
        clamp,
        width,
        height,
        frame,
        device: get("arbor.device")?,
        rect,
        samples,
        done: done.end,
        rays: number("arbor.rays")?,
        seconds: seconds.ok_or_else(|| bad("arbor.seconds", &seconds_text))?,
    })
}

/// `X0,Y0,X1,Y1` with `X0 < X1` and `Y0 < Y1`, as `--crop` takes it.
pub fn parse_rect(s: &str) -> Option<Rect> {
    let v: Vec<u32> = s.split(',').map(|p| p.trim().parse().ok()).collect::<Option<_>>()?;
    let &[x0, y0, x1, y1] = v.as_slice() else { return None };
    let r = Rect { x0, y0, x1, y1 };
    (!r.is_empty()).then_some(r)
}

/// Reads the piece at `path`, checking that it is whole and consistent: the data window is its
/// rectangle, every channel is there, and each pixel's samples added and dropped make the
/// samples it holds.
pub fn read_piece(path: &Path) -> Result<FilmPiece, PieceError> {
    read_pixels(path, piece_info(path)?)
}

/// [`read_info`] of a file that must be a piece.
pub fn piece_info(path: &Path) -> Result<PieceInfo, PieceError> {
    read_info(path)?.ok_or_else(|| foreign(path, "it has no arbor.format attribute (an image, not a piece)"))
}

/// A piece's EXR as the `exr` crate decodes it: the first layer, every channel and attribute.
pub type DecodedPiece = ExrImage<Layer<AnyChannels<FlatSamples>>>;

/// The EXR at `path` decoded whole, as [`read_piece`] decodes it before it checks anything.
pub fn decode(path: &Path) -> Result<DecodedPiece, exr::error::Error> {
    read().no_deep_data().largest_resolution_level().all_channels().first_valid_layer().all_attributes().from_file(path)
}

/// [`read_piece`] of a file whose header has been read: `info`.
fn read_pixels(path: &Path, info: PieceInfo) -> Result<FilmPiece, PieceError> {
    // The pixels read hold 25 channels of 4 bytes; the film is 96 bytes a pixel.
    let what = format!("{}: a {}x{} piece", path.display(), info.rect.width(), info.rect.height());
    crate::memory::check_fits(&what, info.rect.pixel_count() as f64 * 200.0)?;
    let image = decode(path).map_err(|e| exr_error(path, e))?;
    let layer = &image.layer_data;
    check_integrity(path, &image.attributes.other, &layer.attributes.other, &layer.channel_data.list)?;
    let (rect, width, height) = (info.rect, info.width as usize, info.height as usize);
    let display = image.attributes.display_window;
    if display.position != Vec2(0, 0) || display.size != Vec2(width, height) {
        return Err(foreign(path, format!("its display window is not the {width}x{height} image")));
    }
    if layer.attributes.layer_position != Vec2(rect.x0 as i32, rect.y0 as i32)
        || layer.size != Vec2(rect.width() as usize, rect.height() as usize)
    {
        return Err(foreign(path, format!("its data window is not arbor.rect {rect}")));
    }
    let n = rect.pixel_count() as usize;
    let channel = |name: &str| -> Result<&Vec<u32>, PieceError> {
        let c = layer.channel_data.list.iter().find(|c| c.name == *name);
        match c.map(|c| &c.sample_data) {
            Some(FlatSamples::U32(v)) if v.len() == n => Ok(v),
            Some(_) => Err(foreign(path, format!("channel {name} is not {n} u32 samples"))),
            None => Err(foreign(path, format!("channel {name} is missing"))),
        }
    };
    let pair = |name: &str| -> Result<Vec<u64>, PieceError> {
        let (lo, hi) = (channel(&format!("{name}.lo"))?, channel(&format!("{name}.hi"))?);
        Ok(lo.iter().zip(hi).map(|(&l, &h)| u64::from(l) | (u64::from(h) << 32)).collect())
    };
    let count = pair("arbor.count")?;
    let dropped = pair("arbor.dropped")?;
    let mut sums: Vec<[u128; 3]> = vec![[0; 3]; n];
    let mut squares: Vec<[u64; 3]> = vec![[0; 3]; n];
    for (c, name) in ["R", "G", "B"].into_iter().enumerate() {
        for limb in 0..4 {
            for (s, &v) in sums.iter_mut().zip(channel(&format!("arbor.sum.{name}.{limb}"))?) {
                s[c] |= u128::from(v) << (32 * limb);
            }
        }
        for (s, v) in squares.iter_mut().zip(pair(&format!("arbor.sumsq.{name}"))?) {
            s[c] = v;
        }
    }
    let held = u64::from(info.done - info.samples.start);
    // A sample adds at most 2^(44 + 50) units.
    let limit = |count: u64| i128::from(count) << (SAMPLE_LIMIT_LOG2 + FRACTION_BITS);
    let mut film = Film::new(rect.width(), rect.height());
    for (i, px) in film.pixels_mut().iter_mut().enumerate() {
        let sum = sums[i].map(|s| s as i128);
        let sum_sq = squares[i].map(f64::from_bits);
        if count[i].checked_add(dropped[i]) != Some(held)
            || sum.iter().any(|s| s.unsigned_abs() > limit(count[i]).unsigned_abs())
            || sum_sq.iter().any(|s| !(s.is_finite() && *s >= 0.0))
        {
            let (x, y) = (rect.x0 + (i % rect.width() as usize) as u32, rect.y0 + (i / rect.width() as usize) as u32);
            return Err(foreign(
                path,
                format!("pixel ({x}, {y})'s sums do not hold the {held} samples of arbor.samples_done"),
            ));
        }
        *px = PixelAccum { sum, sum_sq, count: count[i], non_finite: dropped[i] };
    }
    Ok(FilmPiece { info, film })
}

/// Refuses the piece at `path` unless its [`INTEGRITY`] attribute is the digest of its other
/// `arbor.*` attributes (`shared` and `own`, the image's and the layer's) and its `channels`.
fn check_integrity(
    path: &Path,
    shared: &std::collections::HashMap<Text, AttributeValue>,
    own: &std::collections::HashMap<Text, AttributeValue>,
    channels: &[AnyChannel<FlatSamples>],
) -> Result<(), PieceError> {
    let mut header = Vec::new();
    let mut stated = None;
    for (key, value) in shared.iter().chain(own) {
        let key = key.to_string();
        if !key.starts_with("arbor.") {
            continue;
        }
        let AttributeValue::Text(value) = value else {
            return Err(foreign(path, format!("{key} is not a text attribute")));
        };
        if key == INTEGRITY {
            stated = Some(value.to_string());
        } else {
            header.push((key, value.to_string()));
        }
    }
    let stated = stated.ok_or_else(|| foreign(path, format!("no {INTEGRITY} attribute")))?;
    let actual = integrity(&header, channels);
    if stated != actual {
        return Err(PieceError::Integrity { path: path.to_path_buf(), stated, actual });
    }
    Ok(())
}

/// Checks that the pieces described by `pieces` (each with its path, for errors) belong
/// together:
/// - the same scene hash, seed, max depth, clamp, resolution, frame and device as the first;
/// - each complete;
/// - for each sample index, the pieces holding it cover the image exactly once, and the
///   sample indices held form one range `A..B` (no overlap, nothing missing).
///
/// Returns what they make together: the first piece's description with the whole image as its
/// rectangle, samples `A..B`, and the rays and seconds of all.
pub fn check_pieces(pieces: &[(PathBuf, PieceInfo)]) -> Result<PieceInfo, PieceError> {
    let (first_path, first) = pieces.first().ok_or(PieceError::Empty)?;
    for (path, info) in pieces {
        if let Some((what, ours, theirs)) = first.differs_from(info) {
            return Err(PieceError::Mismatch { path: path.clone(), first: first_path.clone(), what, ours, theirs });
        }
        if !info.is_complete() {
            return Err(PieceError::Unfinished { path: path.clone(), held: info.held(), asked: info.samples.clone() });
        }
    }
    let samples = check_cover(pieces)?;
    Ok(PieceInfo {
        rect: Rect::full(first.width, first.height),
        samples: samples.clone(),
        done: samples.end,
        rays: pieces.iter().map(|(_, p)| p.rays).sum(),
        seconds: pieces.iter().map(|(_, p)| p.seconds).sum(),
        ..first.clone()
    })
}

/// The order pieces are added in: by samples, then rectangle. The sums are exact, so the order
/// does not change the image; the f64 sums of squares are added in this fixed order so that
/// the standard errors do not depend on the order given either.
fn merge_order(info: &PieceInfo) -> (u32, u32, Rect) {
    (info.samples.start, info.samples.end, info.rect)
}

/// [`check_pieces`], then the whole image's film: the pieces' films added, in any order given.
pub fn merge(pieces: &[(PathBuf, FilmPiece)]) -> Result<(PieceInfo, Film), PieceError> {
    let infos: Vec<(PathBuf, PieceInfo)> = pieces.iter().map(|(p, f)| (p.clone(), f.info.clone())).collect();
    let merged = check_pieces(&infos)?;
    let mut order: Vec<&FilmPiece> = pieces.iter().map(|(_, f)| f).collect();
    order.sort_by_key(|p| merge_order(&p.info));
    let mut film = Film::new(merged.width, merged.height);
    for p in order {
        film.merge_at(&p.film, p.info.rect.x0, p.info.rect.y0);
    }
    Ok((merged, film))
}

/// [`merge`] of the piece files `paths`: their headers are checked first, then each piece is
/// read and added in turn, so that memory holds the image and one piece.
pub fn merge_files(paths: &[PathBuf]) -> Result<(PieceInfo, Film), PieceError> {
    let mut infos = Vec::with_capacity(paths.len());
    for path in paths {
        infos.push((path.clone(), piece_info(path)?));
    }
    let merged = check_pieces(&infos)?;
    let what = format!("{}: the merged {}x{} image", paths[0].display(), merged.width, merged.height);
    let pixels = f64::from(merged.width) * f64::from(merged.height);
    crate::memory::check_fits(&what, pixels * 2.0 * size_of::<PixelAccum>() as f64)?;
    infos.sort_by_key(|(_, info)| merge_order(info));
    let mut film = Film::new(merged.width, merged.height);
    for (path, info) in &infos {
        let piece = read_pixels(path, info.clone())?;
        film.merge_at(&piece.film, info.rect.x0, info.rect.y0);
    }
    Ok((merged, film))
}

/// The sample range the pieces hold for every pixel, or why they do not hold one exactly once.
fn check_cover(pieces: &[(PathBuf, PieceInfo)]) -> Result<Range<u32>, PieceError> {
    let info = &pieces[0].1;
    let total = u64::from(info.width) * u64::from(info.height);
    // The sample axis cut at every piece's ends: within each cut, the same pieces hold every
    // sample index.
    let mut cuts: Vec<u32> = pieces.iter().flat_map(|(_, p)| [p.samples.start, p.samples.end]).collect();
    cuts.sort_unstable();
    cuts.dedup();
    for span in cuts.windows(2) {
        let (a, b) = (span[0], span[1]);
        let holding: Vec<&(PathBuf, PieceInfo)> =
            pieces.iter().filter(|(_, p)| p.samples.start <= a && b <= p.samples.end).collect();
        let mut by_rect: Vec<&(PathBuf, PieceInfo)> = holding.clone();
        by_rect.sort_by_key(|(_, p)| (p.rect.y0, p.rect.x0));
        // Overlaps: rectangles sorted by their top edge; each checked against those that start
        // above its bottom.
        for (i, (pa, a_piece)) in by_rect.iter().enumerate() {
            let ra = a_piece.rect;
            for (pb, b_piece) in &by_rect[i + 1..] {
                let rb = b_piece.rect;
                if rb.y0 >= ra.y1 {
                    break;
                }
                if ra.overlaps(&rb) {
                    let common =
                        Rect { x0: ra.x0.max(rb.x0), y0: ra.y0.max(rb.y0), x1: ra.x1.min(rb.x1), y1: ra.y1.min(rb.y1) };
                    return Err(PieceError::Overlap { a: pa.clone(), b: pb.clone(), samples: a..b, rect: common });
                }
            }
        }
        let covered: u64 = holding.iter().map(|(_, p)| p.rect.pixel_count()).sum();
        if covered != total {
            let pixel = first_uncovered(&holding, info.width, info.height);
            return Err(PieceError::Missing { samples: a..b, covered, total, pixel });
        }
    }
    Ok(cuts[0]..cuts[cuts.len() - 1])
}

/// A pixel no rectangle of `pieces` holds (the top-left-most), for the error's message.
fn first_uncovered(pieces: &[&(PathBuf, PieceInfo)], width: u32, height: u32) -> (u32, u32) {
    let mut held = vec![false; width as usize * height as usize];
    for (_, p) in pieces {
        let r = p.rect;
        for y in r.y0..r.y1 {
            held[(y * width + r.x0) as usize..(y * width + r.x1) as usize].fill(true);
        }
    }
    let i = held.iter().position(|h| !h).unwrap_or(0) as u32;
    (i % width.max(1), i / width.max(1))
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    fn info(rect: Rect, samples: Range<u32>) -> PieceInfo {
        PieceInfo {
            scene_hash: "ab12".into(),
            seed: 7,
            max_depth: 5,
            clamp: Some(10.0),
            width: 6,
            height: 4,
            frame: Some(3),
            device: "cpu".into(),
            rect,
            done: samples.end,
            samples,
            rays: 100,
            seconds: 0.25,
        }
    }

    /// Sample `s` of image pixel (x, y): irregular, over several orders of magnitude.
    fn value(x: u32, y: u32, s: u32) -> Vec3 {
        let h = (x * 7919 + y * 104_729 + s * 1_299_709) % 1000;
        Vec3::new(h as f32 * 1e-3, (h as f32).powi(3) * 1e-5, 1.0 / (1.0 + h as f32))
    }

    /// A piece of samples `samples` of `rect`; with `nan`, the top-left pixel's first sample is
    /// NaN (dropped).
    fn piece_with(rect: Rect, samples: Range<u32>, nan: bool) -> FilmPiece {
        let mut film = Film::new(rect.width(), rect.height());
        for y in rect.y0..rect.y1 {
            for x in rect.x0..rect.x1 {
                for s in samples.clone() {
                    let dropped = nan && (x, y, s) == (rect.x0, rect.y0, samples.start);
                    film.add_sample(x - rect.x0, y - rect.y0, if dropped { Vec3::NAN } else { value(x, y, s) });
                }
            }
        }
        FilmPiece { info: info(rect, samples), film }
    }

    fn piece(rect: Rect, samples: Range<u32>) -> FilmPiece {
        piece_with(rect, samples, false)
    }

    fn scratch(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("arbor-film_file-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_piece_survives_its_file_bit_for_bit() {
        let dir = scratch("roundtrip");
        let p = piece_with(Rect { x0: 1, y0: 2, x1: 5, y1: 4 }, 3..9, true);
        assert_eq!(p.film.non_finite_count(), 1);
        let path = dir.join("p.exr");
        write_piece(&path, &p.info, &p.film).unwrap();
        let back = read_piece(&path).unwrap();
        assert_eq!(back, p);
        assert_eq!(read_info(&path).unwrap(), Some(p.info.clone()));
        // Any EXR reader sees the mean, placed in the whole image.
        let image = crate::image_io::read_exr(&path).unwrap();
        assert_eq!((image.width, image.height), (4, 2));
        assert_eq!(image.pixels, p.film.mean().pixels);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn images_truncated_and_tampered_files_are_refused_by_name() {
        let dir = scratch("refused");
        let p = piece(Rect { x0: 0, y0: 0, x1: 6, y1: 4 }, 0..4);
        let path = dir.join("p.exr");
        write_piece(&path, &p.info, &p.film).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.join("cut.exr");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let e = read_piece(&cut).unwrap_err().to_string();
        assert!(e.starts_with(&cut.display().to_string()), "{e}");
        let image = dir.join("image.exr");
        crate::image_io::write_image(&image, &p.film.mean()).unwrap();
        let e = read_piece(&image).unwrap_err().to_string();
        assert!(e.contains("image.exr: not an Arbor partial film"), "{e}");
        let text = dir.join("text.exr");
        std::fs::write(&text, "hello").unwrap();
        assert!(read_piece(&text).unwrap_err().to_string().contains("text.exr: not a readable EXR"));
        // A piece whose header claims more samples than its pixels hold.
        let mut lying = p.clone();
        lying.info.samples = 0..5;
        lying.info.done = 5;
        let lie = dir.join("lie.exr");
        write_piece(&lie, &lying.info, &lying.film).unwrap();
        let e = read_piece(&lie).unwrap_err().to_string();
        assert!(e.contains("pixel (0, 0)'s sums do not hold the 5 samples"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn bits(film: &Film) -> Vec<u32> {
        film.mean().pixels.iter().flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn any_split_merges_to_the_whole_in_any_order() {
        let whole = piece(Rect::full(6, 4), 0..12);
        let halves = |s: Range<u32>| {
            [
                Rect { x0: 0, y0: 0, x1: 6, y1: 1 },
                Rect { x0: 0, y0: 1, x1: 2, y1: 4 },
                Rect { x0: 2, y0: 1, x1: 6, y1: 4 },
            ]
            .map(|r| piece(r, s.clone()))
        };
        let mut pieces: Vec<(PathBuf, FilmPiece)> = Vec::new();
        for (k, p) in halves(0..5).into_iter().chain(halves(5..6)).chain(halves(6..12)).enumerate() {
            pieces.push((PathBuf::from(format!("p{k}.exr")), p));
        }
        let whole_film = &whole.film;
        for rotation in [0, 4, 7] {
            pieces.rotate_left(rotation);
            let (info, film) = merge(&pieces).unwrap();
            assert_eq!(bits(&film), bits(&whole.film));
            assert_eq!(
                film.pixels().iter().map(|p| (p.sum, p.count)).collect::<Vec<_>>(),
                whole_film.pixels().iter().map(|p| (p.sum, p.count)).collect::<Vec<_>>()
            );
            assert_eq!((info.rect, info.samples), (Rect::full(6, 4), 0..12));
        }
    }

    #[test]
    fn pieces_that_do_not_belong_are_named() {
        let a = (PathBuf::from("a.exr"), piece(Rect { x0: 0, y0: 0, x1: 3, y1: 4 }, 0..4));
        let b = (PathBuf::from("b.exr"), piece(Rect { x0: 3, y0: 0, x1: 6, y1: 4 }, 0..4));
        assert!(merge(&[a.clone(), b.clone()]).is_ok());
        let mut other = b.clone();
        other.1.info.seed = 8;
        let e = merge(&[a.clone(), other]).unwrap_err().to_string();
        assert!(e.starts_with("b.exr: seed is 8, but a.exr has 7"), "{e}");
        let mut other = b.clone();
        other.1.info.scene_hash = "cd34".into();
        assert!(merge(&[a.clone(), other]).unwrap_err().to_string().contains("scene hash is cd34"));
        let mut unfinished = b.clone();
        unfinished.1.info.done = 2;
        assert!(merge(&[a.clone(), unfinished]).unwrap_err().to_string().starts_with("b.exr: unfinished"));
        // Missing: only a; overlapping: a twice, or b's samples overlapping another range.
        let e = merge(std::slice::from_ref(&a)).unwrap_err().to_string();
        assert!(e.contains("held for 12 of the image's 24 pixels (none holds pixel (3, 0))"), "{e}");
        let e = merge(&[a.clone(), b.clone(), (PathBuf::from("c.exr"), a.1.clone())]).unwrap_err().to_string();
        assert!(e.contains("a.exr and c.exr overlap: both hold samples 0..4 of pixels 0,0,3,4"), "{e}");
        let late = (PathBuf::from("late.exr"), piece(Rect::full(6, 4), 2..6));
        let e = merge(&[a.clone(), b.clone(), late]).unwrap_err().to_string();
        assert!(e.contains("overlap: both hold samples 2..4"), "{e}");
        let gap = (PathBuf::from("gap.exr"), piece(Rect::full(6, 4), 5..6));
        let e = merge(&[a, b, gap]).unwrap_err().to_string();
        assert!(e.contains("a piece is missing: samples 4..5 are held for 0 of the image's 24 pixels"), "{e}");
    }
}
