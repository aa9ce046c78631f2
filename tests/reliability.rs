//! Nothing lost, nothing silently wrong (docs/distributed.md): outputs that would overwrite what
//! a run reads are refused before any work; pieces carry a SHA-256 that the merge checks;
//! `--skip-existing` skips only whole outputs, merges included; absurd frame ranges are refused
//! and long ones planned without a list; a full disk is an I/O error (74), a folder named as a
//! piece bad input (2); dropped samples are reported. Every file is made by the test.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use arbor::image_io::{Image, write_image};

use crate::common::temp_dir;

fn render() -> Command {
    Command::new(env!("CARGO_BIN_EXE_render"))
}

fn run(cmd: &mut Command) -> Output {
    let o = cmd.output().unwrap();
    assert!(
        o.status.success(),
        "{cmd:?} failed ({:?}): {}{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// Runs `render`: its exit code, standard output and standard error.
fn outcome(cmd: &mut Command) -> (i32, String, String) {
    let o = cmd.output().unwrap();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (o.status.code().unwrap_or(-1), text(&o.stdout), text(&o.stderr))
}

fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// An image of `w` x `h` whose texels vary, so that they do not compress away.
fn noise(w: u32, h: u32, scale: f32) -> Image {
    let mut image = Image::new(w, h);
    for (i, p) in image.pixels.iter_mut().enumerate() {
        let v = ((i as u32).wrapping_mul(2_654_435_761) >> 8) as f32 / (1 << 24) as f32;
        *p = [v * scale, (1.0 - v) * scale, 0.5 * scale];
    }
    image
}

/// A scene in `dir` with a texture (`texture`) and a sky map (`sky.exr`), both made here.
fn textured_scene(dir: &Path, texture: &str, width: u32, height: u32) -> PathBuf {
    write_image(dir.join(texture), &noise(8, 8, 1.0)).unwrap();
    write_image(dir.join("sky.exr"), &noise(16, 8, 2.0)).unwrap();
    let scene = format!(
        r#"
[camera]
position = [0, 1, 3]
look_at = [0, 0, 0]
fov = 45
resolution = [{width}, {height}]

[render]
spp = 2
max_depth = 3

[environment]
map = "sky.exr"

[materials.floor]
type = "diffuse"
texture = "{texture}"

[[objects]]
shape = "quad"
material = "floor"
rotate = [-90, 0, 0]
scale = 2
"#
    );
    let path = dir.join("scene.toml");
    std::fs::write(&path, scene).unwrap();
    path
}

/// The two tiles of `scene` at 2 spp on the CPU, as `t0.exr` and `t1.exr` in `dir`.
fn tiles(dir: &Path, scene: &Path) -> [PathBuf; 2] {
    [0, 1].map(|i| {
        let piece = dir.join(format!("t{i}.exr"));
        run(render().arg(scene).arg("-o").arg(&piece).args([
            "--tile",
            &format!("{i}/2"),
            "--device",
            "cpu",
            "--quiet",
        ]));
        piece
    })
}

#[test]
fn outputs_that_would_overwrite_what_the_run_reads_are_refused() {
    let dir = temp_dir("overwrite");
    let scene = textured_scene(&dir, "tex_0002.png", 24, 16);
    let (tex, sky) = (dir.join("tex_0002.png"), dir.join("sky.exr"));
    let kept = |files: &[&Path]| files.iter().map(|f| bytes(f)).collect::<Vec<_>>();
    let before = kept(&[&scene, &tex, &sky]);
    let refused = |args: &[OsString], expected: &str| {
        let (code, _, err) = outcome(render().arg(&scene).args(args).args(["--device", "cpu", "--quiet"]));
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(expected), "{args:?}: {err}");
        assert!(err.contains("nothing was written"), "{err}");
        assert_eq!(kept(&[&scene, &tex, &sky]), before, "{args:?} changed an input");
    };
    let o = || OsString::from("-o");
    refused(&[o(), tex.clone().into()], "would overwrite a texture");
    refused(&[o(), sky.clone().into()], "would overwrite the environment map");
    // Through a symbolic link, and a path with `..` in it.
    std::os::unix::fs::symlink(&sky, dir.join("link.exr")).unwrap();
    refused(&[o(), dir.join("link.exr").into()], "would overwrite the environment map");
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    refused(&[o(), dir.join("sub/../tex_0002.png").into()], "would overwrite a texture");
    // The report naming the scene, or the image.
    let out = dir.join("out.png");
    refused(&[o(), out.clone().into(), "--report".into(), scene.clone().into()], "--report");
    assert!(!out.exists());
    let same = dir.join("same.png");
    std::fs::write(&same, b"an earlier image").unwrap();
    refused(&[o(), same.clone().into(), "--report".into(), same.clone().into()], "it would overwrite -o");
    assert_eq!(bytes(&same), b"an earlier image");
    // A frame pattern whose frame 2 is the texture; frames without it render.
    refused(&[o(), dir.join("tex_%04d.png").into(), "--frames".into(), "0..5".into()], "frame 2");
    run(render().arg(&scene).arg("-o").arg(dir.join("tex_%04d.png")).args(["--frames", "3..4", "--quiet"]));
    // Files the scene's loading reads without naming them in the scene: an OBJ's MTL file.
    std::fs::write(dir.join("box.obj"), "mtllib box.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n").unwrap();
    std::fs::write(dir.join("box.mtl"), "newmtl m\nKd 0.5 0.5 0.5\n").unwrap();
    let obj_scene = dir.join("obj.toml");
    let obj_text = std::fs::read_to_string(&scene).unwrap().replace("shape = \"quad\"", "mesh = \"box.obj\"");
    std::fs::write(&obj_scene, obj_text).unwrap();
    // `--report FILE` of `scene`: exit 2, each of `says` on stderr, FILE unchanged.
    let report_kept = |scene: &Path, file: &Path, says: &[&str]| {
        let before = bytes(file);
        let (code, _, err) = outcome(render().arg(scene).arg("-o").arg(dir.join("o.png")).arg("--report").arg(file));
        assert_eq!(code, 2, "{err}");
        assert!(says.iter().all(|s| err.contains(s)), "{err}");
        assert_eq!(bytes(file), before);
    };
    report_kept(&obj_scene, &dir.join("box.mtl"), &["would overwrite a file the scene reads"]);
    // A scene that fails to load halfway (a missing texture) still keeps its report off the
    // files it read.
    let broken = dir.join("broken.toml");
    let broken_text = std::fs::read_to_string(&obj_scene).unwrap().replace("\"tex_0002.png\"", "\"missing.png\"");
    std::fs::write(&broken, broken_text).unwrap();
    report_kept(&broken, &dir.join("box.obj"), &["missing.png", "--report", "not written"]);
    // The state of a whole render (`OUT.partial.exr`) is an output too.
    let state_named = dir.join("s.png");
    std::fs::copy(&sky, dir.join("s.png.partial.exr")).unwrap();
    let sky_copy = dir.join("s.png.partial.exr");
    let scene_text = std::fs::read_to_string(&scene).unwrap().replace("\"sky.exr\"", "\"s.png.partial.exr\"");
    let scene2 = dir.join("scene2.toml");
    std::fs::write(&scene2, scene_text).unwrap();
    let (code, _, err) = outcome(render().arg(&scene2).arg("-o").arg(&state_named).arg("--quiet"));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("-o's state"), "{err}");
    assert!(sky_copy.exists());

    // A merge over one of its own pieces, directly or through a link.
    let [t0, t1] = tiles(&dir, &scene);
    let pieces = kept(&[&t0, &t1]);
    std::os::unix::fs::symlink(&t1, dir.join("t1-link.exr")).unwrap();
    for out in [t0.clone(), dir.join("t1-link.exr")] {
        let (code, _, err) = outcome(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&out));
        assert_eq!(code, 2, "{err}");
        assert!(err.contains("would overwrite a piece"), "{err}");
        assert_eq!(kept(&[&t0, &t1]), pieces);
    }
    let merged = dir.join("m.exr");
    let (code, _, err) =
        outcome(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&merged).arg("--report").arg(&t1));
    assert_eq!((code, kept(&[&t0, &t1])), (2, pieces.clone()), "{err}");
    // Both at fault: the first refusal names `-o`, and the report is not written either.
    let (code, _, err) = outcome(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&t0).arg("--report").arg(&t1));
    assert_eq!((code, kept(&[&t0, &t1])), (2, pieces), "{err}");
    assert!(!merged.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// The EXR at `path` decoded, changed by `change`, and written back whole and well-formed: what a
/// damaged transfer that was then recompressed would leave.
fn tamper(path: &Path, change: &dyn Fn(&mut arbor::distributed::film_file::DecodedPiece)) {
    use exr::prelude::WritableImage;
    let mut image = arbor::distributed::film_file::decode(path).unwrap();
    change(&mut image);
    image.write().to_file(path).unwrap();
}

#[test]
fn pieces_whose_sums_or_header_were_altered_are_refused_by_name() {
    use arbor::distributed::film_file::{PieceError, merge_files};
    use exr::prelude::{AttributeValue, FlatSamples, Text};
    use rand::{RngExt, SeedableRng};

    let dir = temp_dir("integrity");
    let scene = textured_scene(&dir, "tex.png", 12, 8);
    let [t0, t1] = tiles(&dir, &scene);
    let original = bytes(&t1);
    let reference = merge_files(&[t0.clone(), t1.clone()]).unwrap();
    // Property: any one bit of any exact sum, count or sum of squares, flipped, is caught.
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(34);
    for trial in 0..24 {
        std::fs::write(&t1, &original).unwrap();
        let (channel_pick, pixel_pick, bit) = (rng.random::<u32>(), rng.random::<u32>(), rng.random_range(0..32u32));
        tamper(&t1, &|image| {
            let list = &mut image.layer_data.channel_data.list;
            let exact: Vec<usize> =
                (0..list.len()).filter(|&i| list[i].name.to_string().starts_with("arbor.")).collect();
            let c = &mut list[exact[channel_pick as usize % exact.len()]];
            let FlatSamples::U32(samples) = &mut c.sample_data else { panic!("{} is not u32", c.name) };
            let i = pixel_pick as usize % samples.len();
            samples[i] ^= 1 << bit;
        });
        match merge_files(&[t0.clone(), t1.clone()]) {
            Err(PieceError::Integrity { path, .. }) => assert_eq!(path, t1, "trial {trial}"),
            Err(e) => panic!("trial {trial}: refused for another reason: {e}"),
            Ok(merged) => panic!("trial {trial}: an altered piece merged (same image: {})", merged == reference),
        }
    }
    // Through the binary: exit 2, the piece named, nothing written.
    let out = dir.join("merged.exr");
    let (code, _, err) = outcome(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&out));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("{}: damaged or altered", t1.display())) && err.contains("arbor.integrity"), "{err}");
    assert!(!out.exists());
    // A header attribute changed: caught too.
    std::fs::write(&t1, &original).unwrap();
    tamper(&t1, &|image| {
        let attrs = &mut image.layer_data.attributes.other;
        attrs.insert(Text::from("arbor.rays"), AttributeValue::Text(Text::from("1")));
    });
    assert!(matches!(merge_files(&[t0.clone(), t1.clone()]), Err(PieceError::Integrity { .. })));
    // A piece of the format before: refused, naming both versions.
    std::fs::write(&t1, &original).unwrap();
    tamper(&t1, &|image| {
        let attrs = &mut image.layer_data.attributes.other;
        attrs.remove(&Text::from("arbor.integrity"));
        attrs.insert(Text::from("arbor.format"), AttributeValue::Text(Text::from("arbor partial film 1")));
    });
    let (code, _, err) = outcome(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&out));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("arbor partial film 1") && err.contains("arbor partial film 2"), "{err}");
    // Untouched, they merge.
    std::fs::write(&t1, &original).unwrap();
    run(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&out));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn skip_existing_skips_only_whole_outputs() {
    let dir = temp_dir("skip-whole");
    let scene = textured_scene(&dir, "tex.png", 24, 16);
    let skipped = |out: &Path, extra: &[&str]| -> bool {
        let o = run(render().arg(&scene).arg("-o").arg(out).args(["--skip-existing", "--device", "cpu"]).args(extra));
        String::from_utf8_lossy(&o.stdout).contains("complete, skipped")
    };
    for name in ["whole.png", "whole.exr"] {
        let out = dir.join(name);
        // Empty, cut short, of another size: rendered again, and whole afterwards.
        std::fs::write(&out, b"").unwrap();
        assert!(!skipped(&out, &[]), "{name}: an empty file was skipped");
        assert!(arbor::image_io::is_whole_image(&out, 24, 16));
        let full = bytes(&out);
        std::fs::write(&out, &full[..full.len() - 10]).unwrap();
        assert!(!skipped(&out, &[]), "{name}: a truncated file was skipped");
        assert_eq!(bytes(&out), full);
        write_image(&out, &noise(23, 16, 1.0)).unwrap();
        assert!(!skipped(&out, &[]), "{name}: an image of another size was skipped");
        assert!(skipped(&out, &[]), "{name}: a whole output was rendered again");
    }
    // A piece: cut short, or one bit of its sums flipped.
    let piece = dir.join("piece.exr");
    assert!(!skipped(&piece, &["--tile", "0/2"]));
    let full = bytes(&piece);
    std::fs::write(&piece, &full[..full.len() / 2]).unwrap();
    assert!(!skipped(&piece, &["--tile", "0/2"]), "a truncated piece was skipped");
    // With --resume too (what every job passes): a cut piece is no state, rendered again.
    let whole_piece = bytes(&piece);
    let film = arbor::distributed::film_file::read_piece(&piece).unwrap().film;
    std::fs::write(&piece, &whole_piece[..whole_piece.len() / 2]).unwrap();
    let o = run(render().arg(&scene).arg("-o").arg(&piece).args(["--skip-existing", "--resume", "--tile", "0/2"]));
    assert!(String::from_utf8_lossy(&o.stderr).contains("rendering afresh"));
    assert!(arbor::distributed::film_file::read_piece(&piece).unwrap().film == film);
    tamper(&piece, &|image| {
        let c = image.layer_data.channel_data.list.iter_mut().find(|c| c.name.to_string() == "arbor.sum.G.1").unwrap();
        let exr::prelude::FlatSamples::U32(s) = &mut c.sample_data else { panic!() };
        s[3] ^= 1 << 7;
    });
    assert!(!skipped(&piece, &["--tile", "0/2"]), "an altered piece was skipped");
    assert!(skipped(&piece, &["--tile", "0/2"]));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_merge_with_skip_existing_does_nothing_twice() {
    let dir = temp_dir("merge-skip");
    let scene = textured_scene(&dir, "tex.png", 24, 16);
    let [t0, t1] = tiles(&dir, &scene);
    let out = dir.join("merged.exr");
    let merge = || {
        let o = run(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(&out).arg("--skip-existing"));
        String::from_utf8_lossy(&o.stdout).contains("complete, skipped")
    };
    assert!(!merge());
    let whole = bytes(&out);
    let written = std::fs::metadata(&out).unwrap().modified().unwrap();
    assert!(merge(), "a whole merge was done again");
    assert_eq!(std::fs::metadata(&out).unwrap().modified().unwrap(), written);
    std::fs::write(&out, &whole[..whole.len() / 3]).unwrap();
    assert!(!merge(), "a truncated merge output was skipped");
    assert_eq!(bytes(&out), whole);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn frame_ranges_are_planned_without_a_list_and_absurd_ones_refused() {
    let dir = temp_dir("frames");
    let scene = textured_scene(&dir, "tex.png", 8, 8);
    let start = std::time::Instant::now();
    let (code, _, err) =
        outcome(render().arg(&scene).arg("-o").arg(dir.join("f_%d.png")).args(["--frames", "0..4000000000"]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--frames 0..4000000000: 4000000000 frames in one command; at most"), "{err}");
    // A range of ten million frames is planned without a list: a file its last frame would
    // overwrite is found at once, before any frame renders.
    let last = dir.join("f_9999999.png");
    let texture_text = std::fs::read_to_string(&scene).unwrap().replace("\"tex.png\"", "\"f_9999999.png\"");
    std::fs::copy(dir.join("tex.png"), &last).unwrap();
    std::fs::write(&scene, texture_text).unwrap();
    let (code, _, err) =
        outcome(render().arg(&scene).arg("-o").arg(dir.join("f_%d.png")).args(["--frames", "0..10000000"]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("frame 9999999"), "{err}");
    assert!(!dir.join("f_0.png").exists(), "a frame was rendered");
    assert!(start.elapsed().as_secs() < 60, "planning took {:?}", start.elapsed());
    // The library's jobs are made as they are taken.
    let plan_scene = arbor::scene::Scene::load(&scene).unwrap();
    let request = arbor::distributed::Request {
        scene: scene.clone(),
        output: dir.join("g_%d.exr"),
        settings: plan_scene.render,
        tile: None,
        crop: None,
        samples: None,
        frames: None,
        checkpoint: None,
        resume: false,
        skip_existing: false,
    };
    let plan = arbor::distributed::Plan::new(request, &plan_scene).unwrap();
    let mut jobs = plan.jobs(Some(4_000_000_000..u32::MAX), &plan_scene, "hash", "cpu");
    assert_eq!(jobs.len(), (u32::MAX - 4_000_000_000) as usize);
    assert_eq!(jobs.next().unwrap().output, dir.join("g_4000000000.exr"));
    assert_eq!(plan.job(Some(7), &plan_scene, "hash", "cpu").output, dir.join("g_7.exr"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_full_disk_is_an_io_error_and_a_folder_bad_input() {
    let dir = temp_dir("disk-full");
    if !Path::new("/dev/full").exists() {
        println!("skipped: no /dev/full on this system");
        return;
    }
    // Large enough that the encoder itself writes (past any buffer) before the flush.
    let scene = textured_scene(&dir, "tex.png", 160, 120);
    for name in ["full.png", "full.exr"] {
        let out = dir.join(name);
        std::os::unix::fs::symlink("/dev/full", &out).unwrap();
        let (code, _, err) =
            outcome(render().arg(&scene).arg("-o").arg(&out).args(["--spp", "1", "--device", "cpu", "--quiet"]));
        assert_eq!(code, 74, "{name}: {err}");
        assert!(err.contains(&out.display().to_string()), "{err}");
    }
    let [t0, t1] = tiles(&dir, &scene);
    let (code, _, err) = outcome(render().arg("--merge").arg(&t0).arg(&t1).arg("-o").arg(dir.join("full.exr")));
    assert_eq!(code, 74, "{err}");
    // A folder named as a piece is a wrong name, not a failed read.
    let folder = dir.join("pieces");
    std::fs::create_dir_all(&folder).unwrap();
    let (code, _, err) = outcome(render().arg("--merge").arg(&t0).arg(&folder).arg("-o").arg(dir.join("m.exr")));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("{}: not an Arbor partial film: it is a folder", folder.display())), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The piece or state at `path`: the samples it holds, `(first, end)`.
fn held(path: &Path) -> (u32, u32) {
    let info = arbor::distributed::film_file::read_piece(path).unwrap().info;
    (info.samples.start, info.done)
}

/// `render` spawned, then SIGTERM once `ready` says so; its exit code, or `None` where it had
/// not ended `patience` after the signal (it is killed then).
fn terminate(cmd: &mut Command, ready: &dyn Fn() -> bool, patience: std::time::Duration) -> (Option<i32>, String) {
    use std::io::Read;
    let mut child = cmd.stderr(std::process::Stdio::piped()).stdout(std::process::Stdio::null()).spawn().unwrap();
    let waited = std::time::Instant::now();
    while !ready() && waited.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let pid = child.id().to_string();
    assert!(Command::new("kill").args(["-TERM", &pid]).status().unwrap().success());
    let signalled = std::time::Instant::now();
    let code = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status.code();
        }
        if signalled.elapsed() > patience {
            child.kill().unwrap();
            child.wait().unwrap();
            break None;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    (code, err)
}

/// A signal while the scene is still being read (here: a scene that is a FIFO no one writes
/// yet) ends the process with 75 and nothing written, instead of waiting for the first pass.
#[test]
fn a_signal_while_loading_ends_the_run_with_nothing_written() {
    let dir = temp_dir("signal-loading");
    let fifo = dir.join("scene.toml");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let out = dir.join("out.exr");
    let started = std::time::Instant::now();
    let ready = || started.elapsed().as_millis() > 500;
    let patience = std::time::Duration::from_secs(20);
    let (code, err) = terminate(render().arg(&fifo).arg("-o").arg(&out), &ready, patience);
    assert_eq!(code, Some(75), "{err}");
    assert!(err.contains("stopped by a signal while loading"), "{err}");
    assert!(!out.exists() && !dir.join("out.exr.partial.exr").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A signal during a long pass abandons it: the state written holds the last whole pass (here
/// none, the first pass cut), not the pass finished a minute later.
fn a_signal_abandons_the_pass_in_flight(device: &str) {
    let dir = temp_dir(&format!("signal-pass-{device}"));
    let text =
        std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join("cornell-box.toml"))
            .unwrap();
    let scene = dir.join("cornell.toml");
    std::fs::write(&scene, text.replace("resolution = [256, 256]", "resolution = [1024, 1024]")).unwrap();
    let piece = dir.join("piece.exr");
    let report = dir.join("report.json");
    let job = |extra: &[&str]| {
        let mut cmd = render();
        cmd.arg(&scene).arg("-o").arg(&piece).args(["--samples", "0..64", "--builder", "lbvh", "--device", device]);
        // One thread, lavapipe's too: a pass long enough to be signalled in.
        cmd.args(["--threads", "1", "--quiet", "--report"]).arg(&report).args(extra).env("LP_NUM_THREADS", "1");
        cmd
    };
    // Rendering has begun once the BVH is built: a second after the start, on the box.
    let started = std::time::Instant::now();
    let ready = || started.elapsed().as_millis() > 2500;
    let (code, err) = terminate(&mut job(&[]), &ready, std::time::Duration::from_secs(120));
    assert_eq!(code, Some(75), "{err}");
    let json: serde_json::Value = serde_json::from_slice(&bytes(&report)).unwrap();
    let (first, done) = held(&piece);
    assert_eq!(json["frames"][0]["samples_done"], serde_json::json!([first, done]));
    // A CPU pass is 16 samples of every pixel and takes many seconds on one thread at 1024x1024;
    // lavapipe's pass is 4 samples over seconds. A fast GPU finishes passes in milliseconds:
    // there, only that the state is whole can be asserted.
    let slow = device == "cpu" || json["adapter"].as_str().is_some_and(|a| a.contains("llvmpipe"));
    if slow {
        assert_eq!((first, done), (0, 0), "the pass in flight was finished, not abandoned: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_signal_abandons_the_pass_in_flight_on_the_cpu() {
    a_signal_abandons_the_pass_in_flight("cpu");
}

#[cfg(feature = "gpu")]
#[test]
fn a_signal_abandons_the_pass_in_flight_on_the_gpu() {
    if crate::common::gpu_or_skip("a_signal_abandons_the_pass_in_flight_on_the_gpu").is_none() {
        return;
    }
    a_signal_abandons_the_pass_in_flight("gpu");
}

/// Samples dropped (non-finite, or of radiance 2^44 or more) are said on stderr, even with
/// `--quiet`, and in the report's `dropped_samples`: here a merge of pieces whose films dropped
/// some (a valid scene gives none since emitters above 2^40 are refused at load, and next-event
/// estimation is weighted by multiple importance).
#[test]
fn dropped_samples_are_reported_on_stderr_and_in_the_report() {
    use arbor::distributed::film_file::{PieceInfo, write_piece};
    use arbor::render::film::Film;
    use arbor::render::region::Rect;

    let dir = temp_dir("dropped");
    let (w, h) = (6, 4);
    let mut pieces = Vec::new();
    for (i, rect) in [Rect { x0: 0, y0: 0, x1: 3, y1: 4 }, Rect { x0: 3, y0: 0, x1: 6, y1: 4 }].into_iter().enumerate()
    {
        let mut film = Film::new(rect.width(), rect.height());
        for y in 0..rect.height() {
            for x in 0..rect.width() {
                for s in 0..3 {
                    let bad = i == 1 && s == 0 && x < 2;
                    film.add_sample(x, y, if bad { glam::Vec3::NAN } else { glam::Vec3::splat(0.5) });
                }
            }
        }
        let info = PieceInfo {
            scene_hash: "0".repeat(64),
            seed: 1,
            max_depth: 2,
            clamp: None,
            width: w,
            height: h,
            frame: None,
            device: "cpu".into(),
            rect,
            samples: 0..3,
            done: 3,
            rays: 1,
            seconds: 0.5,
        };
        let path = dir.join(format!("p{i}.exr"));
        write_piece(&path, &info, &film).unwrap();
        pieces.push(path);
    }
    let out = dir.join("merged.exr");
    let report = dir.join("merged.json");
    let o = run(render().arg("--merge").args(&pieces).arg("-o").arg(&out).arg("--quiet").arg("--report").arg(&report));
    let err = String::from_utf8_lossy(&o.stderr);
    // Two columns of four rows of the second piece dropped their first sample.
    assert!(err.contains(&format!("{}: 8 samples dropped", out.display())), "{err}");
    let json: serde_json::Value = serde_json::from_slice(&bytes(&report)).unwrap();
    assert_eq!(json["dropped_samples"], 8);
    assert_eq!(json["frames"][0]["dropped_samples"], 8);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The sum of a scene's procedural triangles past its limit is a memory refusal (exit code 3),
/// as every other "does not fit" is, not bad input.
#[test]
fn the_procedural_triangle_limit_is_a_memory_refusal() {
    let dir = temp_dir("procedural-limit");
    let scene = dir.join("hairballs.toml");
    let hairball = |n: u64, seed: u64| {
        format!("\n[[objects]]\nshape = \"hairball\"\nmaterial = \"white\"\ntriangles = {n}\nseed = {seed}\n")
    };
    let text = format!(
        "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n\n\
         [materials.white]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n{}{}",
        hairball(1, 0),
        hairball(100_000_000, 1)
    );
    std::fs::write(&scene, text).unwrap();
    let (code, _, err) = outcome(render().arg(&scene).arg("-o").arg(dir.join("out.png")));
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("objects[1].triangles") && err.contains("more than 100000000"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
