//! Split renders (docs/distributed.md): what one job of a render split by tiles, crops, sample
//! ranges or frames renders, where it writes, and how its pieces merge back into the image one
//! render of the whole would give, bit for bit.
//!
//! This layer sits above [`crate::device`]: it plans jobs and keeps their files, and renders
//! through a [`crate::device::Renderer`]; nothing below it knows of it.
//!
//! - [`plan`]: a request made into the region each job renders and its jobs, skipped, resumed
//!   or started afresh;
//! - [`frames`]: frame-number patterns in output names;
//! - [`overwrite`]: outputs that would replace what the run reads, refused before any work;
//! - [`film_file`]: partial films (an EXR piece with the film's exact sums) and their merge.
//!
//! A scheduler written in Rust runs a job as `render --tile 2/4 -o tile2.exr` does:
//!
//! ```no_run
//! use std::sync::atomic::AtomicBool;
//!
//! use arbor::bvh::Tracing;
//! use arbor::device::{BuilderChoice, Device, Renderer};
//! use arbor::distributed::{Plan, Request, Start};
//! use arbor::scene::Scene;
//!
//! let scene = Scene::load("scenes/cornell-box.toml")?;
//! let request = Request {
//!     scene: "scenes/cornell-box.toml".into(),
//!     output: "tile2.exr".into(),
//!     settings: scene.render,
//!     tile: Some((2, 4)),
//!     crop: None,
//!     samples: None,
//!     frames: None,
//!     checkpoint: Some(60.0),
//!     resume: true,
//!     skip_existing: true,
//! };
//! let plan = Plan::new(request, &scene)?;
//! let frames = plan.frames(&scene)?;
//! let moves = frames.is_some();
//! let (device, hash) = (Device::Cpu, scene.content_hash());
//! plan.check_overwrites(frames.as_ref(), &[], None)?;
//! // Jobs are made as they are taken: a range of frames may hold millions.
//! let count = plan.jobs(frames.clone(), &scene, &hash, device.name()).filter(|job| !job.skips()).count();
//! let (settings, tracing) = (&plan.request.settings, Tracing::from_env(None)?);
//! let first_time = plan.job(frames.as_ref().map(|f| f.start), &scene, &hash, device.name()).time;
//! let mut renderer = Renderer::new(device, &scene, &BuilderChoice::Auto, tracing, settings, count, first_time)?;
//! for job in plan.jobs(frames, &scene, &hash, device.name()) {
//!     let carried = match job.start()? {
//!         Start::Skip => continue,
//!         Start::Fresh | Start::Restart(_) => None,
//!         Start::Resume(frame) => Some(frame),
//!     };
//!     if moves {
//!         renderer.set_time(&scene, job.time)?;
//!     }
//!     renderer.begin_frame();
//!     let frame = job.render(&mut renderer, carried, &|_| {}, &AtomicBool::new(false))?;
//!     job.write(&frame)?;
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod film_file;
pub mod frames;
pub mod overwrite;
pub mod plan;

pub use plan::{Job, JobError, Plan, PlanError, Request, Start};
