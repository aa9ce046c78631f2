//! Exact answers shared by the CPU and GPU render tests: the white furnace, a closed emitting
//! shell (a geometric series), and a diffuse floor under a square area light (Lambert's closed
//! form for a polygon's irradiance).

use arbor::image_io::Image;
use arbor::render::film::Film;
use arbor::scene::Scene;
use glam::Vec3;

const ALBEDO: f32 = 0.5;
const RADIANCE: f32 = 10.0;
/// The light's half width and height above the floor.
const HALF: f32 = 0.25;
const HEIGHT: f32 = 1.0;

/// `scene` with every object and the camera scaled by `s` about the origin.
pub fn scaled_scene(scene: &Scene, s: f32) -> Scene {
    let mut scene = scene.clone();
    for o in &mut scene.objects {
        o.world_from_object = glam::Mat4::from_scale(Vec3::splat(s)) * o.world_from_object;
    }
    scene.camera.position *= s;
    scene.camera.look_at *= s;
    scene.camera.focus_distance *= s;
    scene
}

/// `scenes/furnace.toml` scaled by `scale` and rendered by `render`: a convex sphere of albedo
/// 0.8 under environment radiance 1, so every pixel of the sphere's middle reads 0.8 (to
/// `tolerance`) and the background exactly 1.
pub fn check_furnace(tag: &str, unit: &Scene, scale: f32, tolerance: f32, render: impl FnOnce(&Scene) -> Film) {
    let image = render(&scaled_scene(unit, scale)).mean();
    let at = |x: u32, y: u32| Vec3::from(image.pixels[(y * image.width + x) as usize]);
    let c = image.width / 2;
    for y in c - 20..c + 20 {
        for x in c - 20..c + 20 {
            let p = at(x, y);
            assert!(
                (p - Vec3::splat(0.8)).abs().max_element() < tolerance,
                "{tag}, scale {scale:e}: pixel ({x}, {y}) = {p}"
            );
        }
    }
    for (x, y) in [(0, 0), (image.width - 1, 0), (0, image.height - 1)] {
        assert_eq!(at(x, y), Vec3::ONE, "{tag}, scale {scale:e}: background pixel ({x}, {y})");
    }
}

/// Asserts that `b` is `a` to `tolerance`, relative per channel (absolute below 10^-3), and
/// prints the worst difference, where it is, and how many channels differ at all.
pub fn check_same_image(tag: &str, a: &Image, b: &Image, tolerance: f32) {
    assert_eq!((a.width, a.height), (b.width, b.height), "{tag}: sizes differ");
    let diffs: Vec<f32> = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs() / p[c].abs().max(1e-3)))
        .map(|d| if d.is_nan() { f32::INFINITY } else { d })
        .collect();
    let (at, worst) = diffs.iter().copied().enumerate().fold((0, 0.0f32), |m, (i, d)| if d > m.1 { (i, d) } else { m });
    let pixel = (at / 3) as u32;
    let differing = diffs.iter().filter(|&&d| d > 0.0).count();
    eprintln!(
        "{tag}: worst relative difference {worst:e} at pixel ({}, {}); {differing} of {} channels differ",
        pixel % a.width,
        pixel / a.width,
        diffs.len()
    );
    assert!(worst <= tolerance, "{tag}: images differ by {worst:e} (relative), tolerance {tolerance:e}");
}

/// The extreme scales of the irradiance tests: 2^±40 (about 10^±12, where f32 squares of edge
/// lengths overflow or underflow) and 2^±53 (about 10^±16). Powers of two, so that every
/// coordinate scales exactly and the image can be held to the unit-scale one: at 10^12 rays that
/// graze an edge may round the other way, and on an H100 the image differed there by up to
/// 3·10^-3, while at 2^40 it is the same bit for bit.
pub const EXTREME_SCALES: [f32; 4] =
    [(1u64 << 40) as f32, 1.0 / (1u64 << 40) as f32, (1u64 << 53) as f32, 1.0 / (1u64 << 53) as f32];

/// The irradiance scene, 48×48 pixels: render it with max depth 2 (direct light only).
pub fn irradiance_scene_text() -> String {
    let (albedo, radiance, half, height) = (ALBEDO, RADIANCE, HALF, HEIGHT);
    format!(
        "[camera]\nposition = [0, 2.5, 3]\nlook_at = [0, 0, 0.5]\nfov = 30\nresolution = [48, 48]\n\n\
         [materials.floor]\ntype = \"diffuse\"\nalbedo = [{albedo}, {albedo}, {albedo}]\n\n\
         [materials.lamp]\ntype = \"emissive\"\nradiance = [{radiance}, {radiance}, {radiance}]\n\n\
         [[objects]]\nshape = \"quad\"\nmaterial = \"floor\"\nrotate = [-90, 0, 0]\nscale = 10\n\n\
         [[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\ntranslate = [0, {height}, 0]\nrotate = [90, 0, 0]\nscale = {half}\n"
    )
}

/// Irradiance from a polygon of radiance `l` at point `p` with normal `n` (Lambert's formula):
/// `E = l/2 Σ θ_i n·(u_i × u_{i+1})/|u_i × u_{i+1}|`, `u_i` the unit directions to the vertices.
pub fn polygon_irradiance(p: Vec3, n: Vec3, vertices: &[Vec3], l: f32) -> f32 {
    let u: Vec<Vec3> = vertices.iter().map(|v| (*v - p).normalize()).collect();
    let mut sum = 0.0f64;
    for i in 0..u.len() {
        let (a, b) = (u[i], u[(i + 1) % u.len()]);
        let theta = f64::from(a.dot(b)).clamp(-1.0, 1.0).acos();
        sum += theta * f64::from(n.dot(a.cross(b).normalize()));
    }
    (0.5 * f64::from(l) * sum.abs()) as f32
}

/// Mean and standard error of the mean over the pixels `mask` selects, per channel, and their
/// number.
pub fn region(mean: &Image, stderr: &Image, mask: impl Fn(u32, u32) -> bool) -> (Vec3, Vec3, usize) {
    let (mut sum, mut var, mut n) = (glam::DVec3::ZERO, glam::DVec3::ZERO, 0usize);
    for y in 0..mean.height {
        for x in 0..mean.width {
            if mask(x, y) {
                let i = (y * mean.width + x) as usize;
                sum += Vec3::from(mean.pixels[i]).as_dvec3();
                var += (Vec3::from(stderr.pixels[i]) * Vec3::from(stderr.pixels[i])).as_dvec3();
                n += 1;
            }
        }
    }
    let n_f = n as f64;
    ((sum / n_f).as_vec3(), (var.powf(0.5) / n_f).as_vec3(), n)
}

/// Asserts that every 8×8 block of `film` that sees only the floor matches `albedo/π · E` from
/// the closed form within 3 standard errors, and that at least 20 blocks do; returns the number
/// of blocks and the worst |z|.
pub fn check_irradiance(scene: &Scene, film: &Film) -> (usize, f32) {
    let (image, stderr) = (film.mean(), film.stderr());
    let camera = arbor::render::camera::CameraModel::new(&scene.camera);
    let light = [
        Vec3::new(-HALF, HEIGHT, -HALF),
        Vec3::new(HALF, HEIGHT, -HALF),
        Vec3::new(HALF, HEIGHT, HALF),
        Vec3::new(-HALF, HEIGHT, HALF),
    ];
    // Expected pixel value: the floor's radiance averaged over 4x4 points of the pixel, or None
    // where the pixel sees the light or misses the floor.
    let expected = |x: u32, y: u32| -> Option<f32> {
        let mut sum = 0.0;
        for k in 0..16 {
            let film_pos =
                glam::Vec2::new(x as f32 + (k % 4) as f32 * 0.25 + 0.125, y as f32 + (k / 4) as f32 * 0.25 + 0.125);
            let ray = camera.ray(film_pos, glam::Vec2::ZERO);
            let t_floor = -ray.origin.y / ray.dir.y;
            let t_light = (HEIGHT - ray.origin.y) / ray.dir.y;
            let at_light = ray.at(t_light);
            if t_light > 0.0 && at_light.x.abs() <= HALF * 1.05 && at_light.z.abs() <= HALF * 1.05 {
                return None;
            }
            let p = ray.at(t_floor);
            if t_floor.is_nan() || t_floor <= 0.0 || p.x.abs() > 10.0 || p.z.abs() > 10.0 {
                return None;
            }
            sum += ALBEDO / std::f32::consts::PI * polygon_irradiance(p, Vec3::Y, &light, RADIANCE);
        }
        Some(sum / 16.0)
    };
    let (mut worst, mut blocks) = (0.0f32, 0);
    for by in 0..6 {
        for bx in 0..6 {
            let pixels: Vec<(u32, u32)> = (0..64).map(|k| (bx * 8 + k % 8, by * 8 + k / 8)).collect();
            let Some(want): Option<Vec<f32>> = pixels.iter().map(|&(x, y)| expected(x, y)).collect() else { continue };
            let want = want.iter().sum::<f32>() / 64.0;
            let (got, se, _) = region(&image, &stderr, |x, y| x / 8 == bx && y / 8 == by);
            let z = (got.x - want).abs() / se.x.max(1e-7);
            worst = worst.max(z);
            blocks += 1;
            assert!(z <= 3.0, "block ({bx}, {by}): {} vs closed form {want} (standard error {})", got.x, se.x);
        }
    }
    assert!(blocks >= 20, "only {blocks} blocks see the floor alone");
    (blocks, worst)
}

/// A camera inside a closed diffuse shell of albedo `a` that emits radiance 1 inward sees
/// `1 + a + ... + a^(D-1) = (1 - a^D) / (1 - a)` at max depth D. Renders the shell for three
/// (a, D) with `render(scene, D)` and asserts that the image mean is within 3 standard errors of
/// that. `tag` names the temporary folder and the printed lines.
pub fn check_closed_shell(tag: &str, scale: f32, mut render: impl FnMut(&Scene, u32) -> Film) {
    let dir = std::env::temp_dir().join(format!("arbor-shell-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // An icosphere with its triangles turned inward.
    let sphere = arbor::geometry::TriangleMesh::icosphere(3);
    let mut obj = String::new();
    for p in &sphere.positions {
        obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &sphere.indices {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[2] + 1, t[1] + 1);
    }
    std::fs::write(dir.join("shell.obj"), obj).unwrap();
    for (a, depth) in [(0.5f32, 4u32), (0.8, 3), (0.3, 1)] {
        let text = format!(
            "[camera]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\nfov = 60\nresolution = [24, 24]\n\n\
             [materials.shell]\ntype = \"emissive\"\nradiance = [1, 1, 1]\nalbedo = [{a}, {a}, {a}]\n\n\
             [[objects]]\nmesh = \"shell.obj\"\nmaterial = \"shell\"\n"
        );
        std::fs::write(dir.join("scene.toml"), text).unwrap();
        let scene = scaled_scene(&Scene::load(dir.join("scene.toml")).unwrap_or_else(|e| panic!("{e}")), scale);
        let film = render(&scene, depth);
        let (mean, se, _) = region(&film.mean(), &film.stderr(), |_, _| true);
        let expected = (1.0 - a.powi(depth as i32)) / (1.0 - a);
        let z = ((mean - Vec3::splat(expected)).abs() / se.max(Vec3::splat(1e-7))).max_element();
        eprintln!(
            "{tag} shell at scale {scale:e}, a = {a}, D = {depth}: mean {mean}, expected {expected}, standard error {se}, z {z:.2}"
        );
        assert!(z <= 3.0, "{tag}, scale {scale:e}: a = {a}, D = {depth}: {mean} vs {expected} (standard error {se})");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A floor lit by a square light 10^20 above it, where the square of the distance overflows
/// f32: small enough (half-size 10^17) to be sampled, too powerful to be (5·10^18: its power
/// overflows f32), and so large (10^20) that its area overflows; the last two light the floor
/// only where paths hit them. `render` renders with max depth 2. The floor's radiance must be
/// `albedo/π · E` from the closed form for a point under a square's centre, within 3 standard
/// errors. The first rendered black (no light sample reached it, and hits on it got no
/// weight), the others NaN (0 · ∞ in the density of a light that is never sampled).
pub fn check_distant_lights(tag: &str, mut render: impl FnMut(&Scene) -> Film) {
    for (half, radiance) in [(1e17f64, 1e3f64), (5e18, 100.0), (1e20, 1.0)] {
        let height = 1e20f64;
        let text = format!(
            "[camera]\nposition = [0, 5, 1]\nlook_at = [0, 0, 0]\nfov = 30\nresolution = [16, 16]\n\n\
             [materials.floor]\ntype = \"diffuse\"\nalbedo = [0.7, 0.7, 0.7]\n\n\
             [materials.lamp]\ntype = \"emissive\"\nradiance = [{radiance}, {radiance}, {radiance}]\n\n\
             [[objects]]\nshape = \"quad\"\nmaterial = \"floor\"\nrotate = [-90, 0, 0]\nscale = 10\n\n\
             [[objects]]\nshape = \"quad\"\nmaterial = \"lamp\"\ntranslate = [0, {height:e}, 0]\nrotate = [90, 0, 0]\nscale = {half:e}\n"
        );
        let path = std::env::temp_dir().join(format!("arbor-distant-light-{tag}.toml"));
        let scene = Scene::parse(&text, path).unwrap_or_else(|e| panic!("{e}"));
        let film = render(&scene);
        // Point form factor of a 2a × 2a square at height h, on its axis: with A = a / h,
        // F = (4/π) A/√(1+A²) atan(A/√(1+A²)); E = π L F. The floor seen spans a few units, and
        // the light 10^17 and more: the same E everywhere on it.
        let a = half / height;
        let s = (1.0 + a * a).sqrt();
        let e = radiance * 4.0 * (a / s) * (a / s).atan();
        let want = (0.7 / std::f64::consts::PI * e) as f32;
        let (got, se, n) = region(&film.mean(), &film.stderr(), |_, _| true);
        eprintln!(
            "{tag}: light of half-size {half:e} at {height:e}: {} against {want} (standard error {})",
            got.x, se.x
        );
        assert_eq!(n, 256);
        assert!(
            (got.x - want).abs() <= 3.0 * se.x.max(1e-7),
            "{tag}: light of half-size {half:e}: {} against the closed form {want} (standard error {})",
            got.x,
            se.x
        );
    }
}
