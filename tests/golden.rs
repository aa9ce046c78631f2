//! Golden images: every `scenes/*.toml`, rendered small, against a stored reference mean and its
//! per-pixel standard error (`golden_images/<scene>.exr`, `golden_images/<scene>.stderr.exr`),
//! by a statistical test in the manner of Mitsuba 3's render tests.
//!
//! The goldens are rendered with seed 0 and the test renders with seed 1, so every run exercises
//! the statistics, not a bit-for-bit equality that any change of sampling order would break.
//!
//! The statistic. At 64 spp a pixel's value is far from normal (a rare path to the light or a
//! caustic gives a firefly, and 64 samples often miss the tail, so the per-pixel standard error
//! is itself noisy), so a per-pixel z-test over 10⁴ pixels raises false alarms. Instead:
//! - 8x8-pixel blocks: the difference of the block means of each channel, divided by the
//!   combined standard error `sqrt(Σ (se_ours² + se_golden²)) / n`. A block mean averages 4096
//!   samples, so the central limit theorem makes it close to normal even where pixels are not.
//!   Every block and channel must have |z| below a Bonferroni threshold for `3 * blocks` tests
//!   sharing half of a family-wise false-alarm rate of 10⁻³ per scene.
//! - The whole image: the same z over all pixels, per channel, sharing the other half of that
//!   rate (|z| below about 3.8). A block test only sees changes of several per cent of a block;
//!   this one sees a change of a fraction of a per cent spread over the image.
//! - Pixel channels whose standard error is 0 in both images (constant background, a surface that
//!   reflects its constant surroundings exactly) have no noise to test against: they must agree
//!   within 10⁻⁵ relative, and stay out of the z-tests.
//!
//! On failure the render, the absolute difference and the per-block |z| (per channel, one value
//! for every pixel of its block) are written to `target/golden-failures/`, and the worst blocks
//! are printed with their p-values.
//!
//! `ARBOR_BLESS=1 cargo test --test tests golden` rewrites the goldens instead of comparing.
//!
//! The GPU path tracer (`src/gpu/trace.rs`) is checked against the same goldens by the same
//! comparison ([`scenes_match_their_golden_images_on_the_gpu`]), at the same size, spp and seed;
//! an animated scene is rendered in two levels at the same mid-sequence frame, reached frame by
//! frame as on the CPU. Its failure images are named
//! `<scene>.gpu.{actual,diff,z}.exr`. Without a GPU adapter those tests print why and pass,
//! except under `CI=true`.

use crate::common;

use common::{two_sided_p, z_for_two_sided_p};

use std::path::{Path, PathBuf};

use arbor::bvh::build::Builder;
use arbor::gpu::trace::{self as gpu_trace, GpuForm, GpuScene};
use arbor::image_io::{Image, read_exr, write_image};
use arbor::render::RenderScene;
use arbor::render::film::Film;
use arbor::scene::{Scattering, Scene};

/// Longest side of the test renders, in pixels; the scene's aspect ratio is kept.
const LONGEST_SIDE: u32 = 128;
const SPP: u32 = 64;
const GOLDEN_SEED: u64 = 0;
const TEST_SEED: u64 = 1;
/// Side of the square blocks whose means are compared.
const BLOCK: u32 = 8;
/// Probability that an unchanged renderer fails one scene, if block and image means are normal.
const FAMILY_WISE_ALPHA: f64 = 1e-3;
/// Tolerance of pixel channels that are exact (standard error 0) in both images.
const EXACT_RELATIVE: f64 = 1e-5;

fn manifest_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn golden_dir() -> PathBuf {
    manifest_dir().join("golden_images")
}

fn failure_dir() -> PathBuf {
    manifest_dir().join("target/golden-failures")
}

/// `ARBOR_BLESS` set to anything but empty or `0`.
fn blessing() -> bool {
    std::env::var("ARBOR_BLESS").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// The example scenes, sorted by file name.
fn scene_paths() -> Vec<PathBuf> {
    let dir = manifest_dir().join("scenes");
    let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("cannot list {}: {e}", dir.display()));
    let mut paths: Vec<PathBuf> = entries
        .map(|e| e.unwrap_or_else(|e| panic!("cannot list {}: {e}", dir.display())).path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    paths.sort();
    paths
}

fn stem(path: &Path) -> String {
    path.file_stem().expect("scene path has a file name").to_string_lossy().into_owned()
}

/// The scene at `path`, resized so that its longest side is [`LONGEST_SIDE`].
fn load_small(path: &Path) -> Scene {
    let mut scene = Scene::load(path).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (scene.camera.width, scene.camera.height);
    let longest = w.max(h);
    let scale = |side: u32| (u64::from(side) * u64::from(LONGEST_SIDE) + u64::from(longest) / 2) / u64::from(longest);
    scene.camera.width = scale(w).max(1) as u32;
    scene.camera.height = scale(h).max(1) as u32;
    scene
}

/// A mean image and its per-pixel standard error, as rendered or as stored.
struct Estimate {
    mean: Image,
    stderr: Image,
}

/// An animated scene is rendered at the middle of its frame range, reached frame by frame through
/// the kept top-level tree, as a sequence render gets there.
fn render(scene: &Scene, seed: u64) -> Estimate {
    let (mut rs, _) = RenderScene::build(scene, &"lbvh".parse::<Builder>().unwrap(), common::tracing());
    if let Some(a) = &scene.animation {
        let update = arbor::bvh::dynamic::instances::TopLevelUpdate::Dynamic(Default::default());
        for f in a.frames.start + 1..=a.frames.start + a.frames.len() as u32 / 2 {
            rs.set_time(scene, scene.frame_time(f), &update);
        }
    }
    let mut film = Film::new(rs.width, rs.height);
    rs.render(&mut film, seed, scene.render.max_depth, 0..SPP, &|_| {});
    assert_eq!(film.non_finite_count(), 0, "{}: non-finite samples", scene.path.display());
    Estimate { mean: film.mean(), stderr: film.stderr() }
}

/// [`render`] on the GPU: the same scene, frame, seed and spp. An animated scene is uploaded in
/// two levels at its first frame and brought to the middle of its frame range frame by frame,
/// each frame's top level uploaded again ([`GpuScene::update_instances`]), as a sequence render
/// gets there.
fn render_gpu(scene: &Scene, seed: u64) -> Estimate {
    let ctx = arbor::gpu::GpuContext::shared().unwrap_or_else(|e| panic!("{e}"));
    let lbvh = "lbvh".parse::<Builder>().unwrap();
    let (mut rs, _) = RenderScene::build(scene, &lbvh, arbor::bvh::Tracing::gpu());
    let mut gpu =
        GpuScene::upload(ctx, &rs, GpuForm::default()).unwrap_or_else(|e| panic!("{}: {e}", scene.path.display()));
    if let Some(a) = &scene.animation {
        let update = arbor::bvh::dynamic::instances::TopLevelUpdate::Dynamic(Default::default());
        for f in a.frames.start + 1..=a.frames.start + a.frames.len() as u32 / 2 {
            rs.set_time(scene, scene.frame_time(f), &update);
            gpu.update_instances(ctx, &rs).unwrap_or_else(|e| panic!("{}: {e}", scene.path.display()));
        }
    }
    let out = gpu_trace::render(ctx, &gpu, seed, scene.render.max_depth, SPP)
        .unwrap_or_else(|e| panic!("{}: {e}", scene.path.display()));
    assert_eq!(out.film.non_finite_count(), 0, "{}: non-finite samples on the GPU", scene.path.display());
    Estimate { mean: out.film.mean(), stderr: out.film.stderr() }
}

/// A renderer for [`check`]: the CPU's [`render`] or [`render_gpu`], and the suffix of its
/// failure images.
struct Device {
    render: fn(&Scene, u64) -> Estimate,
    suffix: &'static str,
}

const CPU: Device = Device { render, suffix: "" };
const GPU: Device = Device { render: render_gpu, suffix: ".gpu" };

fn golden_paths(stem: &str) -> (PathBuf, PathBuf) {
    (golden_dir().join(format!("{stem}.exr")), golden_dir().join(format!("{stem}.stderr.exr")))
}

/// The stored golden of scene `stem`; the error says how to make a missing one.
fn read_golden(stem: &str) -> Result<Estimate, String> {
    let (mean_path, stderr_path) = golden_paths(stem);
    let read = |path: &Path| {
        if !path.exists() {
            return Err(format!(
                "{stem}: golden image {} is missing; create it with `ARBOR_BLESS=1 cargo test --test tests golden`",
                path.display()
            ));
        }
        let image = read_exr(path).map_err(|e| format!("{stem}: {e}"))?;
        if image.pixels.iter().flatten().any(|v| !v.is_finite()) {
            return Err(format!("{stem}: {} has non-finite pixels; re-bless it", path.display()));
        }
        Ok(image)
    };
    Ok(Estimate { mean: read(&mean_path)?, stderr: read(&stderr_path)? })
}

/// Renders scene `path` with the golden seed and writes its golden images.
fn bless(path: &Path) {
    let stem = stem(path);
    let golden = render(&load_small(path), GOLDEN_SEED);
    let (mean_path, stderr_path) = golden_paths(&stem);
    std::fs::create_dir_all(golden_dir()).unwrap();
    for (path, image) in [(&mean_path, &golden.mean), (&stderr_path, &golden.stderr)] {
        write_image(path, image).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("ARBOR_BLESS: wrote {}", path.display());
    }
}

/// One block's z-score per channel.
struct BlockZ {
    /// Pixel rectangle: columns `x0..x1`, rows `y0..y1`.
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    z: [f64; 3],
}

/// The outcome of [`compare`].
struct Comparison {
    width: u32,
    blocks: Vec<BlockZ>,
    block_threshold: f64,
    /// Whole-image z per channel.
    image_z: [f64; 3],
    image_threshold: f64,
    /// Pixel channels with standard error 0 in both images.
    exact_count: usize,
    /// Exact pixel channels that disagree: `(x, y, channel, ours, golden)`.
    exact_mismatches: Vec<(u32, u32, usize, f32, f32)>,
}

impl Comparison {
    fn worst_block(&self) -> Option<(&BlockZ, usize)> {
        self.blocks_by_z().into_iter().next()
    }

    /// Every `(block, channel)`, largest |z| first.
    fn blocks_by_z(&self) -> Vec<(&BlockZ, usize)> {
        let mut all: Vec<_> = self.blocks.iter().flat_map(|b| (0..3).map(move |c| (b, c))).collect();
        all.sort_by(|(a, ca), (b, cb)| b.z[*cb].abs().total_cmp(&a.z[*ca].abs()));
        all
    }

    fn worst_block_z(&self) -> f64 {
        self.worst_block().map_or(0.0, |(b, c)| b.z[c].abs())
    }

    fn worst_image_z(&self) -> f64 {
        self.image_z.iter().fold(0.0, |m, z| m.max(z.abs()))
    }

    fn passed(&self) -> bool {
        self.worst_block_z() <= self.block_threshold
            && self.worst_image_z() <= self.image_threshold
            && self.exact_mismatches.is_empty()
    }

    /// One line: the worst statistics against their thresholds.
    fn summary(&self) -> String {
        format!(
            "worst block |z| {:.2} (limit {:.2}, {} blocks x 3 channels), whole-image z [{:.2}, {:.2}, {:.2}] \
             (limit {:.2}), {} of {} exact pixel channels differ",
            self.worst_block_z(),
            self.block_threshold,
            self.blocks.len(),
            self.image_z[0],
            self.image_z[1],
            self.image_z[2],
            self.image_threshold,
            self.exact_mismatches.len(),
            self.exact_count
        )
    }

    /// The `n` worst blocks with their p-values, and the first exact mismatches.
    fn details(&self, n: usize) -> String {
        let tests = 3.0 * self.blocks.len() as f64;
        let mut out = String::new();
        for (b, c) in self.blocks_by_z().into_iter().take(n) {
            let p = two_sided_p(b.z[c]);
            out += &format!(
                "  block x {}..{}, y {}..{}, channel {}: z = {:+.2}, p = {:.2e} (Bonferroni-adjusted {:.2e})\n",
                b.x0,
                b.x1,
                b.y0,
                b.y1,
                ["R", "G", "B"][c],
                b.z[c],
                p,
                (p * tests).min(1.0)
            );
        }
        for (c, z) in self.image_z.iter().enumerate() {
            out +=
                &format!("  whole image, channel {}: z = {:+.2}, p = {:.2e}\n", ["R", "G", "B"][c], z, two_sided_p(*z));
        }
        for (x, y, c, ours, golden) in self.exact_mismatches.iter().take(n) {
            out += &format!("  exact pixel ({x}, {y}) channel {c}: {ours} here, {golden} in the golden\n");
        }
        out
    }

    /// Per-block |z| as an image: each pixel holds its block's |z| per channel.
    fn z_image(&self, height: u32) -> Image {
        let mut image = Image::new(self.width, height);
        for b in &self.blocks {
            for y in b.y0..b.y1 {
                for x in b.x0..b.x1 {
                    image.pixels[(y * self.width + x) as usize] = b.z.map(|z| z.abs() as f32);
                }
            }
        }
        image
    }
}

/// Difference over combined standard error. A variance of 0 means that every pixel channel
/// summed is exact in both images; those are left to the exact check, so the z is 0.
fn z_score(diff: f64, var: f64) -> f64 {
    if var > 0.0 { diff / var.sqrt() } else { 0.0 }
}

/// Compares `ours` with `golden` (same size) block by block and over the whole image; see the
/// module header.
fn compare(ours: &Estimate, golden: &Estimate) -> Comparison {
    let (w, h) = (golden.mean.width, golden.mean.height);
    for image in [&ours.mean, &ours.stderr, &golden.stderr] {
        assert_eq!((image.width, image.height), (w, h), "compare: images of different sizes");
    }
    let blocks_x = w.div_ceil(BLOCK);
    let blocks_y = h.div_ceil(BLOCK);
    let block_count = (blocks_x * blocks_y) as usize;
    // Half the family-wise rate to the 3 * blocks block tests, half to the 3 whole-image tests.
    let block_threshold = z_for_two_sided_p(FAMILY_WISE_ALPHA / 2.0 / (3.0 * block_count as f64));
    let image_threshold = z_for_two_sided_p(FAMILY_WISE_ALPHA / 2.0 / 3.0);

    // Per block and channel, over the noisy pixels: sums of differences and of variances.
    let mut sums = vec![[(0.0f64, 0.0f64); 3]; block_count];
    let (mut exact_count, mut exact_mismatches) = (0, Vec::new());
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let block = &mut sums[((y / BLOCK) * blocks_x + x / BLOCK) as usize];
            for (c, s) in block.iter_mut().enumerate() {
                let (a, g) = (f64::from(ours.mean.pixels[i][c]), f64::from(golden.mean.pixels[i][c]));
                let (sa, sg) = (f64::from(ours.stderr.pixels[i][c]), f64::from(golden.stderr.pixels[i][c]));
                if sa == 0.0 && sg == 0.0 {
                    exact_count += 1;
                    if (a - g).abs() > EXACT_RELATIVE * a.abs().max(g.abs()) {
                        exact_mismatches.push((x, y, c, a as f32, g as f32));
                    }
                    continue;
                }
                s.0 += a - g;
                s.1 += sa * sa + sg * sg;
            }
        }
    }

    let mut image_sums = [(0.0f64, 0.0f64); 3];
    let blocks = (0..block_count)
        .map(|k| {
            let (bx, by) = (k as u32 % blocks_x, k as u32 / blocks_x);
            let z = std::array::from_fn(|c| {
                let (diff, var) = sums[k][c];
                image_sums[c].0 += diff;
                image_sums[c].1 += var;
                // The n² of mean and variance cancel: z = Σd / sqrt(Σvar).
                z_score(diff, var)
            });
            let (x0, y0) = (bx * BLOCK, by * BLOCK);
            BlockZ { x0, y0, x1: (x0 + BLOCK).min(w), y1: (y0 + BLOCK).min(h), z }
        })
        .collect();
    let image_z = image_sums.map(|(diff, var)| z_score(diff, var));
    Comparison { width: w, blocks, block_threshold, image_z, image_threshold, exact_count, exact_mismatches }
}

/// Writes what a person needs to judge a failed comparison; returns the folder.
fn write_failure(stem: &str, ours: &Estimate, golden: &Estimate, cmp: &Comparison) -> PathBuf {
    let dir = failure_dir();
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
    let diff = Image {
        width: ours.mean.width,
        height: ours.mean.height,
        pixels: ours
            .mean
            .pixels
            .iter()
            .zip(&golden.mean.pixels)
            .map(|(a, g)| std::array::from_fn(|c| (a[c] - g[c]).abs()))
            .collect(),
    };
    for (kind, image) in [("actual", &ours.mean), ("diff", &diff), ("z", &cmp.z_image(ours.mean.height))] {
        let path = dir.join(format!("{stem}.{kind}.exr"));
        write_image(&path, image).unwrap_or_else(|e| panic!("{e}"));
    }
    dir
}

/// Removes the failure images of an earlier run, so that none is mistaken for a current one.
fn clear_failure(stem: &str) {
    for kind in ["actual", "diff", "z"] {
        let _ = std::fs::remove_file(failure_dir().join(format!("{stem}.{kind}.exr")));
    }
}

/// Renders scene `path` with the test seed on `device` and compares it with its golden; the
/// error names the scene.
fn check(path: &Path, device: &Device) -> Result<(), String> {
    let scene_stem = stem(path);
    let golden = read_golden(&scene_stem)?;
    // The name of this device's failure images (and its messages).
    let stem = format!("{scene_stem}{}", device.suffix);
    let ours = (device.render)(&load_small(path), TEST_SEED);
    let (w, h) = (ours.mean.width, ours.mean.height);
    for image in [&golden.mean, &golden.stderr] {
        if (image.width, image.height) != (w, h) {
            return Err(format!(
                "{stem}: golden is {}x{}, the render {w}x{h}; re-bless with `ARBOR_BLESS=1 cargo test --test tests golden`",
                image.width, image.height
            ));
        }
    }
    let cmp = compare(&ours, &golden);
    println!("{stem}: {}", cmp.summary());
    if cmp.passed() {
        clear_failure(&stem);
        return Ok(());
    }
    let dir = write_failure(&stem, &ours, &golden, &cmp);
    eprintln!(
        "{stem}: differs from its golden: {}\n{}  images: {}/{stem}.{{actual,diff,z}}.exr",
        cmp.summary(),
        cmp.details(5),
        dir.display()
    );
    Err(format!("{stem}: render differs from golden_images/{scene_stem}.exr ({})", cmp.summary()))
}

#[test]
fn scenes_match_their_golden_images() {
    let paths = scene_paths();
    assert!(!paths.is_empty(), "no scenes/*.toml");
    if blessing() {
        eprintln!("ARBOR_BLESS is set: rewriting the golden images (seed {GOLDEN_SEED}) instead of comparing");
        for path in &paths {
            bless(path);
        }
        return;
    }
    let failures: Vec<String> = paths.iter().filter_map(|p| check(p, &CPU).err()).collect();
    assert!(failures.is_empty(), "golden image comparison failed:\n{}", failures.join("\n"));
}

/// Every scene rendered on the GPU against the CPU's goldens, by the same comparison.
#[test]
fn scenes_match_their_golden_images_on_the_gpu() {
    if blessing() || common::gpu_or_skip("scenes_match_their_golden_images_on_the_gpu").is_none() {
        return;
    }
    let paths = scene_paths();
    assert!(!paths.is_empty(), "no scenes/*.toml");
    let failures: Vec<String> = paths.iter().filter_map(|p| check(p, &GPU).err()).collect();
    assert!(failures.is_empty(), "GPU golden image comparison failed:\n{}", failures.join("\n"));
}

/// The Cornell box at test size and its golden; `None` (with a message) while blessing, when the
/// golden is being rewritten.
fn cornell_box() -> Option<(Scene, Estimate)> {
    if blessing() {
        eprintln!("skipping: ARBOR_BLESS is set");
        return None;
    }
    let scene = load_small(&manifest_dir().join("scenes/cornell-box.toml"));
    Some((scene, read_golden("cornell-box").unwrap_or_else(|e| panic!("{e}"))))
}

#[test]
fn golden_comparison_rejects_a_3_percent_albedo_change() {
    let Some((mut scene, golden)) = cornell_box() else { return };
    let white = scene.materials.iter_mut().find(|m| m.name == "white").expect("cornell-box has a white material");
    match &mut white.scattering {
        Scattering::Diffuse { albedo } => *albedo *= 1.03,
        other => panic!("cornell-box: white is {other:?}, expected diffuse"),
    }
    // An expected failure: nothing is written to target/golden-failures.
    let cmp = compare(&render(&scene, TEST_SEED), &golden);
    println!("cornell-box, white albedo x 1.03: {}", cmp.summary());
    assert!(!cmp.passed(), "a 3% albedo change passed the golden comparison: {}", cmp.summary());
}

/// The same deliberately wrong Cornell box, rendered on the GPU: the GPU check fails it too.
#[test]
fn golden_comparison_rejects_a_3_percent_albedo_change_on_the_gpu() {
    if common::gpu_or_skip("golden_comparison_rejects_a_3_percent_albedo_change_on_the_gpu").is_none() {
        return;
    }
    let Some((mut scene, golden)) = cornell_box() else { return };
    let white = scene.materials.iter_mut().find(|m| m.name == "white").expect("cornell-box has a white material");
    match &mut white.scattering {
        Scattering::Diffuse { albedo } => *albedo *= 1.03,
        other => panic!("cornell-box: white is {other:?}, expected diffuse"),
    }
    let cmp = compare(&render_gpu(&scene, TEST_SEED), &golden);
    println!("cornell-box on the GPU, white albedo x 1.03: {}", cmp.summary());
    assert!(!cmp.passed(), "a 3% albedo change passed the GPU golden comparison: {}", cmp.summary());
}

#[test]
fn golden_comparison_accepts_another_seed() {
    let Some((scene, golden)) = cornell_box() else { return };
    let cmp = compare(&render(&scene, 2), &golden);
    println!("cornell-box, seed 2: {}", cmp.summary());
    assert!(cmp.passed(), "cornell-box with seed 2 failed:\n{}", cmp.details(5));
}

#[test]
fn normal_tail_matches_known_values() {
    for (z, p) in [(0.0, 1.0), (1.959_963_985, 0.05), (3.0, 2.699_796e-3), (5.0, 5.733_031e-7)] {
        assert!((two_sided_p(z) / p - 1.0).abs() < 1e-6, "p({z}) = {}, want {p}", two_sided_p(z));
        assert!((z_for_two_sided_p(p) - z).abs() < 1e-5, "z({p}) = {}, want {z}", z_for_two_sided_p(p));
    }
}
