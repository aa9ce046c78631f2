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
//! - [`film_file`]: partial films (an EXR piece with the film's exact sums) and their merge.

pub mod film_file;
pub mod frames;
pub mod plan;

pub use plan::{Job, JobError, Plan, PlanError, Request, Start};
