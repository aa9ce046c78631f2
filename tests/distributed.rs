//! Renders split into jobs, as a scheduler runs them (docs/distributed.md): `--tile`, `--crop`
//! and `--samples` write partial films, `render --merge` makes the image, and that image is a
//! single render's bit for bit (the EXR files are compared byte for byte) whatever the split and
//! the order of the pieces. Checkpoints, a real SIGTERM and `--resume`; `--skip-existing`;
//! `--report`; exit codes; and bad input, refused by name with nothing written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::temp_dir;

fn render() -> Command {
    Command::new(env!("CARGO_BIN_EXE_render"))
}

fn repo_scene(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)
}

/// The Cornell box at `width` x `height` in `dir` (its shapes are built in: no mesh files).
fn small_cornell(dir: &Path, width: u32, height: u32) -> PathBuf {
    let text = std::fs::read_to_string(repo_scene("cornell-box.toml")).unwrap();
    let text = text.replace("resolution = [256, 256]", &format!("resolution = [{width}, {height}]"));
    assert!(text.contains(&format!("[{width}, {height}]")));
    let path = dir.join("cornell.toml");
    std::fs::write(&path, text).unwrap();
    path
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

/// Runs `render` and returns its exit code and standard error.
fn fails(cmd: &mut Command) -> (i32, String) {
    let o = cmd.output().unwrap();
    (o.status.code().unwrap_or(-1), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn bytes(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The pieces of `splits` (each a list of extra flags), rendered with `common`, then merged in
/// the order `order` gives; asserts the merge is the single render's file, byte for byte.
fn check_split(dir: &Path, tag: &str, common: &[&str], splits: &[Vec<String>], order: &[usize], single: &Path) {
    let mut pieces = Vec::new();
    for (k, split) in splits.iter().enumerate() {
        let piece = dir.join(format!("{tag}-{k}.exr"));
        run(render().args(common).arg("-o").arg(&piece).args(split).arg("--quiet"));
        pieces.push(piece);
    }
    let merged = dir.join(format!("{tag}-merged.exr"));
    let mut merge = render();
    merge.arg("--merge");
    for &i in order {
        merge.arg(&pieces[i]);
    }
    let o = run(merge.arg("-o").arg(&merged));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains(&format!("{} pieces merged", splits.len())), "{stdout}");
    assert!(bytes(&merged) == bytes(single), "{tag}: the merged image differs from the single render");
}

fn strings(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

/// The splits the issue names, on one device: 4 tiles, 3 unequal sample ranges, tiles x sample
/// ranges and crops, each merged in a shuffled order to the single render's EXR, byte for byte.
fn splits_merge_exactly(device: &str) {
    let dir = temp_dir(&format!("splits-{device}"));
    let scene = small_cornell(&dir, 40, 30);
    let scene = scene.to_str().unwrap();
    let common = [scene, "--spp", "7", "--device", device, "--threads", "2"];
    let single = dir.join("single.exr");
    run(render().args(common).arg("-o").arg(&single).arg("--quiet"));
    let tiles: Vec<Vec<String>> = (0..4).map(|i| strings(&["--tile", &format!("{i}/4")])).collect();
    check_split(&dir, "tiles", &common, &tiles, &[2, 0, 3, 1], &single);
    let ranges: Vec<Vec<String>> = ["0..1", "1..5", "5..7"].iter().map(|r| strings(&["--samples", r])).collect();
    check_split(&dir, "ranges", &common, &ranges, &[1, 2, 0], &single);
    let mut both = Vec::new();
    for r in ["0..3", "3..7"] {
        for t in ["0/2", "1/2"] {
            both.push(strings(&["--tile", t, "--samples", r]));
        }
    }
    check_split(&dir, "tiles-x-ranges", &common, &both, &[3, 0, 2, 1], &single);
    // Crops that are not a grid: a band on top, two unequal rectangles under it.
    let crops: Vec<Vec<String>> =
        ["0,0,40,7", "0,7,13,30", "13,7,40,30"].iter().map(|c| strings(&["--crop", c])).collect();
    check_split(&dir, "crops", &common, &crops, &[2, 1, 0], &single);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn splits_merge_to_the_single_render_bit_for_bit_on_the_cpu() {
    splits_merge_exactly("cpu");
}

#[cfg(feature = "gpu")]
#[test]
fn splits_merge_to_the_single_render_bit_for_bit_on_the_gpu() {
    if crate::common::gpu_or_skip("splits_merge_to_the_single_render_bit_for_bit_on_the_gpu").is_none() {
        return;
    }
    splits_merge_exactly("gpu");
}

/// Pieces that do not make one render are refused, naming the piece (or what is missing), with
/// exit code 2 and no output written.
#[test]
fn pieces_that_do_not_belong_together_are_refused() {
    let dir = temp_dir("refused");
    let scene = small_cornell(&dir, 24, 16);
    let scene = scene.to_str().unwrap();
    let common = [scene, "--spp", "4", "--device", "cpu", "--quiet"];
    let piece = |name: &str, extra: &[&str]| {
        let path = dir.join(name);
        run(render().args(common).arg("-o").arg(&path).args(extra));
        path
    };
    let t0 = piece("t0.exr", &["--tile", "0/2"]);
    let t1 = piece("t1.exr", &["--tile", "1/2"]);
    let t1_seed = piece("t1-seed.exr", &["--tile", "1/2", "--seed", "9"]);
    let t1_late = piece("t1-late.exr", &["--tile", "1/2", "--samples", "2..4"]);
    let whole = dir.join("whole.exr");
    run(render().args(common).arg("-o").arg(&whole));
    let out = dir.join("merged.png");
    let merge = |pieces: &[&Path]| {
        let mut cmd = render();
        cmd.arg("--merge").args(pieces).arg("-o").arg(&out);
        let (code, err) = fails(&mut cmd);
        assert!(!out.exists(), "an image was written for refused pieces: {err}");
        (code, err)
    };
    let name = |p: &Path| p.display().to_string();
    let (code, err) = merge(&[&t0]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("a piece is missing: samples 0..4"), "{err}");
    let (code, err) = merge(&[&t0, &t1, &t0]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("{} and {} overlap", name(&t0), name(&t0))), "{err}");
    let (_, err) = merge(&[&t0, &t1, &t1_late]);
    assert!(err.contains("overlap: both hold samples 2..4"), "{err}");
    let (code, err) = merge(&[&t0, &t1_seed]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("{}: seed is 9, but {} has 0", name(&t1_seed), name(&t0))), "{err}");
    // Another scene: the same box, one material changed.
    let other = dir.join("other.toml");
    std::fs::write(&other, std::fs::read_to_string(scene).unwrap().replace("0.885809", "0.885")).unwrap();
    let t1_other = dir.join("t1-other.exr");
    run(render().arg(&other).args(&common[1..]).arg("-o").arg(&t1_other).args(["--tile", "1/2"]));
    let (_, err) = merge(&[&t0, &t1_other]);
    assert!(err.contains(&format!("{}: scene hash is", name(&t1_other))), "{err}");
    // An image is not a piece; nor is a truncated piece, nor a file that is not an EXR.
    let (code, err) = merge(&[&t0, &whole]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("{}: not an Arbor partial film", name(&whole))), "{err}");
    let cut = dir.join("cut.exr");
    let b = bytes(&t1);
    std::fs::write(&cut, &b[..b.len() - 100]).unwrap();
    let (code, err) = merge(&[&t0, &cut]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&name(&cut)), "{err}");
    let text = dir.join("text.exr");
    std::fs::write(&text, "not an image").unwrap();
    let (code, err) = merge(&[&t0, &text]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("{}: not a readable EXR", name(&text))), "{err}");
    // The pieces that belong together merge, to the whole render's image.
    let merged = dir.join("merged.exr");
    run(render().arg("--merge").arg(&t1).arg(&t0).arg("-o").arg(&merged));
    assert!(bytes(&merged) == bytes(&whole));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Arguments that cannot make a piece: clear errors naming the flag, exit code 2, nothing
/// written.
#[test]
fn bad_splits_are_refused_before_any_work() {
    let dir = temp_dir("bad-splits");
    let scene = small_cornell(&dir, 24, 16);
    let out = dir.join("p.exr");
    for (flags, expected) in [
        (vec!["--tile", "4/4"], "--tile"),
        (vec!["--tile", "0/0"], "--tile"),
        (vec!["--tile", "0/500"], "has no grid of 500 tiles"),
        (vec!["--crop", "0,0,25,16"], "--crop 0,0,25,16: not inside the image"),
        (vec!["--crop", "5,5,5,9"], "--crop"),
        (vec!["--samples", "2..9"], "--samples 2..9: past the render's 8 samples per pixel"),
        (vec!["--samples", "3..3"], "--samples"),
        (vec!["--checkpoint", "0"], "--checkpoint must be"),
    ] {
        let (code, err) = fails(render().arg(&scene).arg("-o").arg(&out).args(["--spp", "8"]).args(&flags));
        assert_eq!(code, 2, "{flags:?}: {err}");
        assert!(err.contains(expected), "{flags:?}: {err}");
        assert!(!out.exists(), "{flags:?} wrote {}", out.display());
    }
    let png = dir.join("p.png");
    let (code, err) = fails(render().arg(&scene).arg("-o").arg(&png).args(["--tile", "0/2"]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("writes a partial film, an EXR"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--skip-existing` leaves a complete output alone; `--resume` of a finished piece is refused
/// unless `--skip-existing` makes it a no-op; `--report` says what ran.
#[test]
fn skip_existing_resume_and_report() {
    let dir = temp_dir("hygiene");
    let scene = small_cornell(&dir, 24, 16);
    let piece = dir.join("t1.exr");
    let report = dir.join("t1.json");
    let job = |extra: &[&str]| {
        let mut cmd = render();
        cmd.arg(&scene).arg("-o").arg(&piece).args(["--spp", "4", "--tile", "1/2", "--device", "cpu"]).args(extra);
        cmd
    };
    run(job(&["--quiet", "--report"]).arg(&report));
    let json: serde_json::Value = serde_json::from_slice(&bytes(&report)).unwrap();
    assert_eq!(json["mode"], "render");
    assert_eq!(json["device"], "cpu");
    assert_eq!(json["tile"], "1/2");
    assert_eq!(json["rect"], serde_json::json!([12, 0, 24, 16]));
    assert_eq!(json["samples"], serde_json::json!([0, 4]));
    assert_eq!(json["texture_bytes"], 0);
    assert_eq!(json["exit_code"], 0);
    assert_eq!(json["frames"][0]["status"], "rendered");
    assert_eq!(json["frames"][0]["samples_done"], serde_json::json!([0, 4]));
    assert!(json["frames"][0]["rays"].as_u64().unwrap() > 0);
    assert!(json["bvh"]["build_ms"].as_f64().is_some() && json["scene_hash"].as_str().unwrap().len() == 64);
    let written = std::fs::metadata(&piece).unwrap().modified().unwrap();
    let o = run(job(&["--skip-existing", "--resume", "--report"]).arg(&report));
    assert!(String::from_utf8_lossy(&o.stdout).contains("complete, skipped"));
    assert_eq!(std::fs::metadata(&piece).unwrap().modified().unwrap(), written, "a skipped output was rewritten");
    let json: serde_json::Value = serde_json::from_slice(&bytes(&report)).unwrap();
    assert_eq!(json["frames"][0]["status"], "skipped");
    let (code, err) = fails(&mut job(&["--resume"]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(&format!("--resume: {} is finished", piece.display())), "{err}");
    // A state of another render is not resumed.
    let (code, err) = fails(&mut job(&["--resume", "--seed", "3"]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("is a piece of another render: its seed is 0, this render's 3"), "{err}");
    // A whole image: skipped when there.
    let image = dir.join("whole.png");
    run(render().arg(&scene).arg("-o").arg(&image).args(["--spp", "1", "--quiet"]));
    let o = run(render().arg(&scene).arg("-o").arg(&image).args(["--spp", "1", "--skip-existing"]));
    assert!(String::from_utf8_lossy(&o.stdout).contains("complete, skipped"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A render stopped by a real SIGTERM writes its state and exits 75; `--resume` finishes it to
/// the image an uninterrupted render gives, byte for byte; the state of a whole render is
/// removed once the image is written.
fn interrupt_and_resume(device: &str, spp: &str) {
    let dir = temp_dir(&format!("resume-{device}"));
    let scene = small_cornell(&dir, 32, 24);
    let common = [scene.to_str().unwrap(), "--spp", spp, "--device", device, "--threads", "1", "--quiet"];
    let single = dir.join("single.exr");
    run(render().args(common).arg("-o").arg(&single));
    for split in [false, true] {
        let out = dir.join(if split { "piece.exr" } else { "image.exr" });
        let state = if split { out.clone() } else { dir.join("image.exr.partial.exr") };
        let extra: &[&str] = if split { &["--samples", &format!("0..{spp}")] } else { &[] };
        let mut child =
            render().args(common).arg("-o").arg(&out).args(extra).args(["--checkpoint", "0.01"]).spawn().unwrap();
        // The first checkpoint shows the render is under way: stop it as a scheduler would.
        let start = std::time::Instant::now();
        while !state.exists() {
            assert!(start.elapsed().as_secs() < 120, "no checkpoint at {}", state.display());
            if let Some(status) = child.try_wait().unwrap() {
                panic!("the render ended ({status}) before it was signalled: make it longer");
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let kill = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
        assert!(kill.success());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(75), "split {split}: a signalled render exits 75");
        let info = arbor::distributed::film_file::read_info(&state).unwrap().expect("a partial film");
        assert!(!info.is_complete(), "split {split}: the state is complete: make the render longer");
        let o = run(render()
            .args(common)
            .arg("-o")
            .arg(&out)
            .args(extra)
            .arg("--resume")
            .arg("--report")
            .arg(dir.join("r.json")));
        assert!(o.stdout.is_empty());
        let json: serde_json::Value = serde_json::from_slice(&bytes(&dir.join("r.json"))).unwrap();
        assert_eq!(json["frames"][0]["status"], "resumed");
        if split {
            let merged = dir.join("merged.exr");
            run(render().arg("--merge").arg(&out).arg("-o").arg(&merged));
            assert!(bytes(&merged) == bytes(&single), "{device}: the resumed piece differs from the single render");
        } else {
            assert!(bytes(&out) == bytes(&single), "{device}: the resumed image differs from the single render");
            assert!(!state.exists(), "the state of a finished render is left behind");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_signalled_render_resumes_to_the_same_image_on_the_cpu() {
    interrupt_and_resume("cpu", "2000");
}

#[cfg(feature = "gpu")]
#[test]
fn a_signalled_render_resumes_to_the_same_image_on_the_gpu() {
    if crate::common::gpu_or_skip("a_signalled_render_resumes_to_the_same_image_on_the_gpu").is_none() {
        return;
    }
    interrupt_and_resume("gpu", "400");
}

/// The library's plan of a split render, used without the binary, as a scheduler's wrapper
/// would: 4 tiles of two frames cover the image once, each job's output and state follow the
/// frame pattern; a whole render keeps its state beside the output; a state half rendered is
/// resumed, finished, then skipped; a finished or foreign state is refused with `render`'s
/// messages.
#[test]
fn the_library_plans_tiles_of_frames_and_decides_resume_and_skip() {
    use arbor::device::{BuilderChoice, Device, Renderer};
    use arbor::distributed::film_file::write_piece;
    use arbor::distributed::{Plan, PlanError, Request, Start};
    use arbor::render::region::{Region, tile_rect};
    use arbor::scene::{RenderSettings, Scene};

    let dir = temp_dir("library-plan");
    let scene_path = small_cornell(&dir, 40, 30);
    let scene = Scene::load(&scene_path).unwrap();
    let request = |i: u32| Request {
        scene: scene_path.clone(),
        output: dir.join("f%02d").join(format!("tile{i}.exr")),
        settings: RenderSettings { spp: 4, max_depth: 3, ..scene.render },
        tile: Some((i, 4)),
        crop: None,
        samples: None,
        frames: Some(3..5),
        checkpoint: None,
        resume: true,
        skip_existing: true,
    };
    let mut pixels = 0;
    for i in 0..4 {
        let plan = Plan::new(request(i), &scene).unwrap();
        assert_eq!(plan.region, Region { rect: tile_rect(i, 4, 40, 30).unwrap(), samples: 0..4 });
        pixels += plan.region.rect.pixel_count();
        let frames = plan.frames(&scene).unwrap();
        assert_eq!(frames, Some(3..5));
        let jobs: Vec<_> = plan.jobs(frames, &scene, "hash", "cpu").collect();
        let got: Vec<_> = jobs.iter().map(|j| (j.frame, j.output.clone(), j.state.clone())).collect();
        let file = |f: u32| dir.join(format!("f{f:02}")).join(format!("tile{i}.exr"));
        assert_eq!(got, [(Some(3), file(3), file(3)), (Some(4), file(4), file(4))]);
        assert!(jobs.iter().all(|j| matches!(j.start(), Ok(Start::Fresh))));
    }
    assert_eq!(pixels, 40 * 30);

    // A still, whole: its state is beside the image.
    let still = Request { tile: None, frames: None, output: dir.join("still.png"), ..request(0) };
    let plan = Plan::new(still, &scene).unwrap();
    let frames = plan.frames(&scene).unwrap();
    let jobs: Vec<_> = plan.jobs(frames, &scene, "hash", "cpu").collect();
    assert_eq!(jobs.len(), 1);
    assert_eq!((jobs[0].frame, &jobs[0].state), (None, &dir.join("still.png.partial.exr")));

    // Tile 1's first frame, half rendered and stopped: resumed, finished, then skipped.
    let plan = Plan::new(request(1), &scene).unwrap();
    let frames = plan.frames(&scene).unwrap();
    let hash = scene.content_hash();
    let job = plan.jobs(frames.clone(), &scene, &hash, "cpu").next().unwrap();
    let settings = plan.request.settings;
    let mut renderer =
        Renderer::new(Device::Cpu, &scene, &BuilderChoice::Auto, crate::common::tracing(), &settings, 1, job.time)
            .unwrap();
    let half = Region { samples: 0..2, ..plan.region.clone() };
    let frame = renderer.render_region(arbor::render::pass::Pass::new(&settings, half.clone())).unwrap();
    write_piece(&job.state, &job.held(&frame), &frame.film).unwrap();
    assert!(!job.is_complete());
    let Ok(Start::Resume(carried)) = job.start() else { panic!("a state of 2 of 4 samples is resumed") };
    assert_eq!(carried.samples, 2);
    let frame = job.render(&mut renderer, Some(carried), &|_| {}, &std::sync::atomic::AtomicBool::new(false)).unwrap();
    assert_eq!(frame.samples, 4);
    job.write(&frame).unwrap();
    assert!(job.is_complete());
    assert!(matches!(job.start(), Ok(Start::Skip)));
    // Without --skip-existing, a finished piece is refused; so is a state of another seed.
    let finished = arbor::distributed::Job { skip_existing: false, ..job.clone() };
    let e = finished.start().err().expect("a finished piece is not resumed");
    assert!(matches!(e, PlanError::Finished { .. }));
    let finished_message = format!(
        "--resume: {} is finished (samples 0..4): nothing to resume; --skip-existing skips finished outputs",
        job.state.display()
    );
    assert_eq!(e.to_string(), finished_message);
    let other = Request { settings: RenderSettings { seed: settings.seed + 1, ..settings }, ..request(1) };
    let plan = Plan::new(other, &scene).unwrap();
    let job = plan.jobs(frames, &scene, &hash, "cpu").next().unwrap();
    let Err(e) = job.start() else { panic!("a state of another seed is refused") };
    assert!(
        e.to_string().starts_with(&format!("--resume: {} is a piece of another render: its seed", job.state.display())),
        "{e}"
    );

    // Bad requests: typed, with `render`'s messages.
    let e = Plan::new(Request { tile: Some((4, 4)), ..request(0) }, &scene).unwrap_err();
    assert_eq!(e.to_string(), "--tile 4/4: the tile number must be below 4 (tiles count from 0)");
    let e = Plan::new(Request { samples: Some(2..9), ..request(0) }, &scene).unwrap_err();
    assert!(matches!(e, PlanError::Samples { spp: 4, .. }), "{e}");
}
