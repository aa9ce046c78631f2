//! Environment maps: loading and its errors, the furnace under a constant map, the mapping
//! against Mitsuba 3's lookup, importance sampling against uniform sampling (agreement, and the
//! error at equal samples), and the two devices against each other.
//!
//! Tolerances are numbers of combined standard errors of region means (from the films'
//! per-pixel variances), except where the answer is exact.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arbor::device::{BuilderChoice, Device, Renderer};
use arbor::image_io::{Image, write_image};
use arbor::render::film::Film;
use arbor::scene::{RenderSettings, Scene};
use arbor::texture::environment::Sampling;
use glam::{DVec3, Vec3};

use crate::render_accuracy::devices;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arbor-environment-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn render(device: Device, scene: &Scene, spp: u32, max_depth: u32, seed: u64) -> Film {
    let settings = RenderSettings { spp, max_depth, seed, time: None, clamp: None };
    let choice = BuilderChoice::Fixed("lbvh".parse().unwrap());
    let mut r = Renderer::new(device, scene, &choice, crate::common::tracing(), &settings, 1, 0.0).unwrap();
    let film = r.render(&settings, &|_| {}).unwrap().film;
    assert_eq!(film.non_finite_count(), 0);
    film
}

/// A map of `width` x `height` texels from `f(u, v)` at texel centres.
fn map_image(width: u32, height: u32, f: impl Fn(f32, f32) -> [f32; 3]) -> Image {
    let pixels = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| f((x as f32 + 0.5) / width as f32, (y as f32 + 0.5) / height as f32))
        .collect();
    Image { width, height, pixels }
}

/// A blue sky over a dark ground with a small sun about 35° up (2 × 2 texels of a 128 x 64 map,
/// about 1/2000 of the sphere) that gives most of the light.
fn sun_sky() -> Image {
    sky(1.0)
}

/// [`sun_sky`] with its sun `sun` times as bright.
fn sky(sun: f32) -> Image {
    map_image(128, 64, |u, v| {
        if (u - 0.3).abs() < 1.0 / 128.0 && (v - 0.3).abs() < 1.0 / 64.0 {
            [3000.0 * sun, 2600.0 * sun, 2000.0 * sun]
        } else if v < 0.5 {
            [0.25, 0.35, 0.6]
        } else {
            [0.05, 0.04, 0.03]
        }
    })
}

const SUN_SCENE: &str = "[camera]\nposition = [0, 1.2, 4]\nlook_at = [0, 0.4, 0]\nfov = 40\nresolution = [40, 30]\n\
    [environment]\nmap = \"sky.exr\"\n\
    [materials.white]\ntype = \"diffuse\"\nalbedo = [0.7, 0.7, 0.7]\n\
    [materials.metal]\ntype = \"conductor\"\nroughness = 0.3\nbase_color = [0.9, 0.8, 0.6]\n\
    [[objects]]\nshape = \"quad\"\nmaterial = \"white\"\nrotate = [-90, 0, 0]\nscale = 3\n\
    [[objects]]\nshape = \"sphere\"\nmaterial = \"white\"\ntranslate = [-0.7, 0.5, 0]\nscale = 0.5\n\
    [[objects]]\nshape = \"sphere\"\nmaterial = \"metal\"\ntranslate = [0.7, 0.5, 0]\nscale = 0.5\n";

fn sun_scene(name: &str) -> Scene {
    let dir = temp_dir(name);
    write_image(dir.join("sky.exr"), &sun_sky()).unwrap();
    std::fs::write(dir.join("scene.toml"), SUN_SCENE).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// `scene` with its map drawn from as `sampling` says.
fn sampled(scene: &Scene, sampling: Sampling) -> Scene {
    let mut scene = scene.clone();
    let env = scene.environment.as_mut().unwrap();
    env.map = Some(Arc::new(env.map.as_ref().unwrap().with_sampling(sampling)));
    scene
}

/// Each quadrant's mean and its standard error, per channel.
pub(crate) fn quadrant_means(film: &Film) -> Vec<([f64; 3], [f64; 3])> {
    let (mean, se) = (film.mean(), film.stderr());
    let (w, h) = (film.width() as usize, film.height() as usize);
    let mut out = Vec::new();
    for (qx, qy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        let (mut m, mut v, mut n) = ([0.0f64; 3], [0.0f64; 3], 0.0);
        for y in qy * h / 2..(qy + 1) * h / 2 {
            for x in qx * w / 2..(qx + 1) * w / 2 {
                for c in 0..3 {
                    m[c] += f64::from(mean.pixels[y * w + x][c]);
                    v[c] += f64::from(se.pixels[y * w + x][c]).powi(2);
                }
                n += 1.0;
            }
        }
        out.push((m.map(|s| s / n), v.map(|s| s.sqrt() / n)));
    }
    out
}

/// The quadrant means of the sum of two independent estimates, from theirs: the means add, and
/// the variances.
pub(crate) fn quadrant_sums(a: &[([f64; 3], [f64; 3])], b: &[([f64; 3], [f64; 3])]) -> Vec<([f64; 3], [f64; 3])> {
    a.iter()
        .zip(b)
        .map(|((ma, sa), (mb, sb))| {
            (std::array::from_fn(|c| ma[c] + mb[c]), std::array::from_fn(|c| sa[c].hypot(sb[c])))
        })
        .collect()
}

/// Fails unless every quadrant of `a` and `b` agrees within `z` combined standard errors.
pub(crate) fn assert_agree(what: &str, a: &Film, b: &Film, z: f64) {
    assert_quadrants_agree(what, quadrant_means(a), quadrant_means(b), z);
}

pub(crate) fn assert_quadrants_agree(what: &str, a: Vec<([f64; 3], [f64; 3])>, b: Vec<([f64; 3], [f64; 3])>, z: f64) {
    for (q, ((ma, sa), (mb, sb))) in a.into_iter().zip(b).enumerate() {
        for c in 0..3 {
            let score = (ma[c] - mb[c]) / sa[c].hypot(sb[c]).max(1e-12);
            assert!(score.abs() < z, "{what}: quadrant {q} channel {c}: {} against {} (z = {score:.2})", ma[c], mb[c]);
        }
    }
}

/// A diffuse sphere of albedo 0.8 under a constant map of radiance 1 (an EXR, and the same as a
/// Radiance HDR file) reflects exactly 0.8: every bounce leaves the convex sphere, and light
/// sampling of the map with MIS must add up to that, not just the BSDF sampling a constant
/// `radiance` takes. The background is the map, 1 within rounding. On both devices.
#[test]
fn a_constant_map_is_the_furnace() {
    let dir = temp_dir("furnace");
    write_image(dir.join("white.exr"), &map_image(16, 8, |_, _| [1.0; 3])).unwrap();
    let rgb = vec![image::Rgb([1.0f32; 3]); 16 * 8];
    let file = std::fs::File::create(dir.join("white.hdr")).unwrap();
    image::codecs::hdr::HdrEncoder::new(file).encode(&rgb, 16, 8).unwrap();
    let text = "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [32, 32]\n\
                [environment]\nmap = \"white.exr\"\nrotate = [10, 20, 30]\n\
                [materials.white]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
                [[objects]]\nshape = \"sphere\"\nsubdivisions = 4\nmaterial = \"white\"\n";
    std::fs::write(dir.join("exr.toml"), text).unwrap();
    std::fs::write(dir.join("hdr.toml"), text.replace("white.exr", "white.hdr")).unwrap();
    let mut cases = Vec::new();
    for device in devices("a_constant_map_is_the_furnace") {
        cases.push((device, "exr.toml"));
    }
    cases.push((Device::Cpu, "hdr.toml"));
    for (device, file) in cases {
        let scene = Scene::load(dir.join(file)).unwrap();
        let what = format!("{} {file}", device.name());
        let film = render(device, &scene, 64, 8, 3);
        let (mean, se) = (film.mean(), film.stderr());
        let (mut sum, mut var, mut n) = (0.0f64, 0.0f64, 0.0);
        for (i, (m, s)) in mean.pixels.iter().zip(&se.pixels).enumerate() {
            let (x, y) = ((i % 32) as f32 + 0.5 - 16.0, (i / 32) as f32 + 0.5 - 16.0);
            let r = x.hypot(y);
            if r < 9.0 {
                sum += f64::from(m[0]);
                var += f64::from(s[0]).powi(2);
                n += 1.0;
            } else if r > 13.0 {
                assert!((m[0] - 1.0).abs() < 1e-5, "{what}: background pixel {i} is {}", m[0]);
            }
        }
        let (mean, se) = (sum / n, var.sqrt() / n);
        assert!(se > 0.0 && se < 2e-3, "{what}: standard error {se}");
        assert!((mean - 0.8).abs() < 4.0 * se + 1e-5, "{what}: the sphere's mean {mean} ± {se}, want 0.8");
    }
}

/// The sun map: sampling it by luminance agrees with sampling it uniformly (the same image
/// within noise, quadrant by quadrant), and at equal samples has at most a quarter of uniform
/// sampling's relative mean squared error against a converged render.
#[test]
fn luminance_sampling_beats_uniform_sampling_on_a_sun() {
    let scene = sun_scene("sun");
    let (luminance, uniform) = (sampled(&scene, Sampling::Luminance), sampled(&scene, Sampling::Uniform));
    let reference = render(Device::Cpu, &luminance, 1024, 3, 1).mean();
    let rel_mse = |film: &Film| {
        let mean = film.mean();
        let mut sum = 0.0f64;
        for (p, r) in mean.pixels.iter().zip(&reference.pixels) {
            for c in 0..3 {
                sum += f64::from(p[c] - r[c]).powi(2) / (f64::from(r[c]).powi(2) + 1e-3);
            }
        }
        sum / (mean.pixels.len() * 3) as f64
    };
    let (a, b) = (render(Device::Cpu, &luminance, 16, 3, 2), render(Device::Cpu, &uniform, 16, 3, 2));
    let ratio = rel_mse(&a) / rel_mse(&b);
    println!("relative MSE at 16 spp: luminance {:.3e}, uniform {:.3e}, ratio {ratio:.4}", rel_mse(&a), rel_mse(&b));
    assert!(ratio <= 0.25, "luminance sampling's relative MSE is {ratio} of uniform sampling's");
    let (a, b) = (render(Device::Cpu, &luminance, 64, 3, 4), render(Device::Cpu, &uniform, 256, 3, 5));
    assert_agree("luminance against uniform sampling", &a, &b, 4.5);
}

/// The GPU's importance sampling and MIS render the sun scene as the CPU's do, and a map that
/// is turned by `rotate` as well.
#[test]
fn both_devices_render_a_sun_map_alike() {
    let scene = sun_scene("devices");
    let mut turned = scene.clone();
    let dir = temp_dir("devices-turned");
    write_image(dir.join("sky.exr"), &sun_sky()).unwrap();
    std::fs::write(
        dir.join("scene.toml"),
        SUN_SCENE.replace("map = \"sky.exr\"", "map = \"sky.exr\"\nrotate = [0, 70, 0]"),
    )
    .unwrap();
    turned.environment = Scene::load(dir.join("scene.toml")).unwrap().environment;
    let cpu = render(Device::Cpu, &scene, 256, 3, 7);
    let cpu_turned = render(Device::Cpu, &turned, 256, 3, 7);
    for device in devices("both_devices_render_a_sun_map_alike") {
        if matches!(device, Device::Cpu) {
            continue;
        }
        let gpu = render(device, &scene, 256, 3, 8);
        assert_agree("GPU against CPU", &gpu, &cpu, 4.5);
        let gpu_turned = render(device, &turned, 256, 3, 8);
        assert_agree("GPU against CPU, the map turned", &gpu_turned, &cpu_turned, 4.5);
    }
}

/// `rotate` turns the map as it turns an object: what the map shows along `d` is seen along
/// `R d`.
#[test]
fn rotate_turns_the_map_like_an_object() {
    let dir = temp_dir("rotate");
    write_image(dir.join("sky.exr"), &sun_sky()).unwrap();
    let base = "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n[environment]\nmap = \"sky.exr\"\n";
    std::fs::write(dir.join("a.toml"), base).unwrap();
    std::fs::write(dir.join("b.toml"), format!("{base}rotate = [0, 90, 0]\nscale = [2, 2, 2]\n")).unwrap();
    let a = Scene::load(dir.join("a.toml")).unwrap().environment.unwrap();
    let b = Scene::load(dir.join("b.toml")).unwrap().environment.unwrap();
    assert_eq!((a.radiance, b.radiance), (Vec3::ONE, Vec3::splat(2.0)));
    let (a, b) = (a.map.unwrap(), b.map.unwrap());
    let turn = glam::Mat3::from_rotation_y(90f32.to_radians());
    let mut rng = crate::common::rng(9);
    for _ in 0..500 {
        let d = crate::common::unit_vec3(&mut rng);
        let (x, y) = (a.eval(d), b.eval(turn * d));
        assert!((x - y).abs().max_element() <= 1e-3 * x.max_element().max(1.0), "{d}: {x} against {y}");
    }
    // The map's -z (its left edge) is seen along -x once turned.
    let (l, r) = (a.eval(Vec3::NEG_Z), b.eval(Vec3::NEG_X));
    assert!((l - r).abs().max_element() < 1e-4, "{l} {r}");
}

fn load_err(dir: &Path, environment: &str) -> String {
    let text = format!(
        "[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n[environment]\n{environment}"
    );
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    match Scene::load(dir.join("scene.toml")) {
        Ok(_) => panic!("`{environment}` loaded"),
        Err(e) => e.to_string(),
    }
}

/// Bad `[environment]` tables and bad map files: an error naming the scene file, the line and
/// the key, and the map file where it is at fault; never a panic.
#[test]
fn bad_environments_name_file_line_and_key() {
    let dir = temp_dir("errors");
    write_image(dir.join("sky.exr"), &sun_sky()).unwrap();
    write_image(dir.join("nan.exr"), &map_image(4, 2, |u, _| if u > 0.5 { [f32::NAN, 0.0, 0.0] } else { [1.0; 3] }))
        .unwrap();
    let bytes = std::fs::read(dir.join("sky.exr")).unwrap();
    std::fs::write(dir.join("cut.exr"), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(dir.join("cut.hdr"), b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n\x02\x02").unwrap();
    std::fs::write(dir.join("text.hdr"), "not an image").unwrap();
    std::fs::write(dir.join("sky.png"), "png").unwrap();
    let scene = dir.join("scene.toml").display().to_string();
    let cases: &[(&str, &str, &[&str])] = &[
        ("", "environment", &["radiance", "map"]),
        ("map = \"sky.exr\"\nradiance = [1, 1, 1]\n", "environment.radiance", &["either"]),
        ("radiance = [1, 1, 1]\nscale = 2\n", "environment.scale", &["only a `map`"]),
        ("radiance = [1, 1, 1]\nrotate = [0, 1, 0]\n", "environment.rotate", &["only a `map`"]),
        ("map = \"sky.exr\"\nscale = -1\n", "environment.scale", &["negative"]),
        ("map = \"sky.exr\"\nscale = [1, 2]\n", "environment.scale", &["3"]),
        ("map = \"sky.exr\"\nrotate = [0, nan, 0]\n", "environment.rotate", &["finite"]),
        ("map = \"\"\n", "environment.map", &["empty"]),
        ("map = \"missing.exr\"\n", "environment.map", &["missing.exr", "cannot read"]),
        ("map = \"sky.png\"\n", "environment.map", &["sky.png", ".exr or .hdr"]),
        ("map = \"nan.exr\"\n", "environment.map", &["nan.exr", "pixel (2, 0)", "finite"]),
        ("map = \"cut.exr\"\n", "environment.map", &["cut.exr"]),
        ("map = \"cut.hdr\"\n", "environment.map", &["cut.hdr"]),
        ("map = \"text.hdr\"\n", "environment.map", &["text.hdr"]),
        ("map = \"sky.exr\"\nsun = 1\n", "environment", &["sun"]),
    ];
    for (environment, key, words) in cases {
        let e = load_err(&dir, environment);
        assert!(e.starts_with(&format!("{scene}:")), "`{environment}`: {e}");
        assert!(e.contains(&format!(": {key}")), "`{environment}`: want key {key}: {e}");
        for w in *words {
            assert!(e.contains(w), "`{environment}`: want `{w}` in: {e}");
        }
    }
}

/// Light adds up: the sun scene with a lamp beside the map renders as the map's image plus the
/// lamp's, each rendered alone. Next-event estimation then picks between the map and the area
/// lights, and each MIS weight must count the other's share; a weight that forgot it would
/// count light twice or lose it. The lamp is large, so that BSDF samples carry much of its
/// light and their weight matters. On both devices.
#[test]
fn a_map_and_a_lamp_add_up() {
    let dir = temp_dir("add-up");
    // A dim sun: its noise would hide the lamp's light.
    write_image(dir.join("sky.exr"), &sky(0.01)).unwrap();
    let lamp = |emits: bool| {
        let kind = if emits {
            "type = \"emissive\"\nradiance = [2, 2, 2]\nalbedo = [0.5, 0.5, 0.5]"
        } else {
            "type = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]"
        };
        format!(
            "[materials.lamp]\n{kind}\n[[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\ntranslate = [0, 2.2, 0]\n\
             rotate = [90, 0, 0]\nscale = 1.5\n"
        )
    };
    let scene = |name: &str, map: bool, emits: bool| {
        let mut text = format!("{SUN_SCENE}{}", lamp(emits));
        if !map {
            text = text.replace("[environment]\nmap = \"sky.exr\"\n", "");
        }
        std::fs::write(dir.join(name), text).unwrap();
        Scene::load(dir.join(name)).unwrap()
    };
    let (both, map_only, lamp_only) =
        (scene("both.toml", true, true), scene("map.toml", true, false), scene("lamp.toml", false, true));
    for device in devices("a_map_and_a_lamp_add_up") {
        let map = quadrant_means(&render(device, &map_only, 128, 3, 11));
        let lamp = quadrant_means(&render(device, &lamp_only, 128, 3, 12));
        let sum = quadrant_sums(&map, &lamp);
        let together = quadrant_means(&render(device, &both, 128, 3, 13));
        assert_quadrants_agree(&format!("{}: map + lamp against each alone", device.name()), together, sum, 4.5);
    }
}

/// A 16 x 9 sky of sharp steps for [`a_sky_seen_directly_is_mitsubas_lookup`]: bright rows over
/// a dark ground, the step between rows 2 and 3 (45° and 22.5° up), each column and channel
/// scaled differently so that a column or a channel out of place shows too.
fn stepped_sky() -> Image {
    const ROWS: [f32; 9] = [3.0, 5.0, 8.0, 0.25, 0.2, 0.15, 0.1, 0.1, 0.1];
    let pixels = (0..9usize)
        .flat_map(|y| (0..16usize).map(move |x| (x, y)))
        .map(|(x, y)| {
            let column = 1.0 + 0.5 * (x % 3) as f32 + 0.1 * x as f32;
            [1.0, 0.8, 0.6].map(|tint| ROWS[y] * column * tint)
        })
        .collect();
    Image { width: 16, height: 9, pixels }
}

/// Mitsuba 3's `envmap` lookup (v3.9 on) of `sky` along `d`, in the map's frame: `u =
/// atan2(d.x, -d.z) / 2π` and `v = acos(d.y) / π` (`docs/scene-format.md`), texel column `j` at
/// `u = (j + 0.5) / W` (periodic), row `i` at `v = i / (H - 1)` (`H` at least 2), bilinear
/// between them.
fn mitsuba_lookup(sky: &Image, d: DVec3) -> [f64; 3] {
    use std::f64::consts::PI;
    let (w, h) = (sky.width as usize, sky.height as usize);
    let u = (d.x.atan2(-d.z) / (2.0 * PI)).rem_euclid(1.0);
    let v = d.y.clamp(-1.0, 1.0).acos() / PI;
    let x = u * w as f64 - 0.5;
    let fx = x - x.floor();
    let j0 = (x.floor() as i64).rem_euclid(w as i64) as usize;
    let j1 = (j0 + 1) % w;
    let y = v * (h - 1) as f64;
    let i0 = (y.floor() as usize).min(h - 2);
    let (i1, fy) = (i0 + 1, y - i0 as f64);
    let t = |i: usize, j: usize, c: usize| f64::from(sky.pixels[i * w + j][c]);
    std::array::from_fn(|c| {
        (1.0 - fy) * ((1.0 - fx) * t(i0, j0, c) + fx * t(i0, j1, c))
            + fy * ((1.0 - fx) * t(i1, j0, c) + fx * t(i1, j1, c))
    })
}

/// A pinhole camera at the origin, as `src/render/camera.rs`'s docs give it (up is +y).
#[derive(Clone, Copy)]
struct PinholeAt {
    look_at: DVec3,
    /// The vertical opening angle, in degrees.
    fov: f64,
    width: u32,
    height: u32,
}

impl PinholeAt {
    /// The unit direction through film position `(px, py)`, in pixels from the top-left corner.
    fn ray(&self, px: f64, py: f64) -> DVec3 {
        let forward = self.look_at.normalize();
        let right = forward.cross(DVec3::Y).normalize();
        let up = right.cross(forward);
        let tan_y = (self.fov.to_radians() * 0.5).tan();
        let tan_x = tan_y * f64::from(self.width) / f64::from(self.height);
        let sx = (2.0 * px / f64::from(self.width) - 1.0) * tan_x;
        let sy = (1.0 - 2.0 * py / f64::from(self.height)) * tan_y;
        (forward + right * sx + up * sy).normalize()
    }

    /// Each pixel's mean of `radiance` over its square (where a render spreads its samples), by
    /// the midpoint rule on a 32 x 32 grid; row-major.
    fn pixel_means(&self, radiance: impl Fn(DVec3) -> [f64; 3]) -> Vec<[f64; 3]> {
        const GRID: u32 = 32;
        let weight = 1.0 / f64::from(GRID * GRID);
        (0..self.height)
            .flat_map(|y| (0..self.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let mut sum = [0.0f64; 3];
                for k in 0..GRID * GRID {
                    let px = f64::from(x) + (f64::from(k % GRID) + 0.5) / f64::from(GRID);
                    let py = f64::from(y) + (f64::from(k / GRID) + 0.5) / f64::from(GRID);
                    let l = radiance(self.ray(px, py));
                    sum = std::array::from_fn(|c| sum[c] + l[c] * weight);
                }
                sum
            })
            .collect()
    }
}

/// Issue 34: a map renders as in Mitsuba 3, whose `envmap` puts texel row `i` at `v = i / (H -
/// 1)`, row 0 straight up and the last row straight down (Arbor had put it at `(i + 0.5) / H`,
/// up to half a texel off towards the poles; the two agree only at the horizon). A sky of sharp
/// steps seen directly (`max_depth = 1`, no objects), on both devices, against
/// [`mitsuba_lookup`] of the texels read back from the file, averaged over each pixel on a
/// 32 x 32 grid of film positions through the pinhole camera of `src/render/camera.rs`'s docs
/// (a pixel's samples are spread uniformly over it). Tolerance: every pixel channel within 5 of
/// its standard errors (the spread of the lookup over the pixel, at 256 samples) plus 10⁻³ of
/// its value (f32 directions, the quadrature). The old rows miss by about 380 standard errors on
/// the CPU and 400 on the GPU (lavapipe), and Mitsuba's columns before 3.9 (`u = j / W`) by 570.
#[test]
fn a_sky_seen_directly_is_mitsubas_lookup() {
    let dir = temp_dir("mitsuba-rows");
    write_image(dir.join("sky.exr"), &stepped_sky()).unwrap();
    let sky = arbor::image_io::read_exr(dir.join("sky.exr")).unwrap();
    let camera = PinholeAt { look_at: DVec3::new(1.0, 0.7, 0.3), fov: 40.0, width: 32, height: 24 };
    let PinholeAt { look_at, fov, width, height } = camera;
    std::fs::write(
        dir.join("scene.toml"),
        format!(
            "[camera]\nposition = [0, 0, 0]\nlook_at = [{}, {}, {}]\nfov = {fov}\nresolution = [{width}, {height}]\n\
             [environment]\nmap = \"sky.exr\"\n",
            look_at.x, look_at.y, look_at.z
        ),
    )
    .unwrap();
    let scene = Scene::load(dir.join("scene.toml")).unwrap();
    let reference = camera.pixel_means(|d| mitsuba_lookup(&sky, d));
    for device in devices("a_sky_seen_directly_is_mitsubas_lookup") {
        let film = render(device, &scene, 256, 1, 21);
        let (mean, se) = (film.mean(), film.stderr());
        let mut worst = (0.0f64, 0usize, 0usize);
        for (i, want) in reference.iter().enumerate() {
            for (c, &want) in want.iter().enumerate() {
                let (got, se) = (f64::from(mean.pixels[i][c]), f64::from(se.pixels[i][c]));
                let excess = (got - want).abs() - 1e-3 * want;
                let z = excess / se.max(1e-12);
                if excess > 0.0 && z > worst.0 {
                    worst = (z, i, c);
                }
            }
        }
        let (z, i, c) = worst;
        let (x, y) = (i % width as usize, i / width as usize);
        println!(
            "{}: worst pixel ({x}, {y}) channel {c}: {} against {} ± {} (z = {z:.1})",
            device.name(),
            mean.pixels[i][c],
            reference[i][c],
            se.pixels[i][c]
        );
        assert!(
            z <= 5.0,
            "{}: pixel ({x}, {y}) channel {c} is {}, Mitsuba's lookup {} (standard error {}; z = {z:.1} past 10⁻³)",
            device.name(),
            mean.pixels[i][c],
            reference[i][c],
            se.pixels[i][c]
        );
    }
}
