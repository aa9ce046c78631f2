//! Building a BVH: the builders, each in its own module, and the builders by name
//! ([`Builder`]: what `bvh-bench --builders` and `render --builder` accept).
//!
//! | name | what |
//! |---|---|
//! | `lbvh` | [`crate::bvh::build::lbvh`] |
//! | `lbvh+prbvh` | LBVH optimised by [`crate::bvh::build::prbvh`] (aggressive locks) |
//! | `lbvh+prbvh-conservative` | the same with conservative locks |
//! | `binned-sah` | [`crate::bvh::build::binned_sah`] |
//! | `binned-sah+prbvh` | binned SAH optimised by PRBVH |
//! | `ploc`, `ploc-R` | [`crate::bvh::build::ploc`] with radius 16, or R |
//! | `ploc+prbvh`, `ploc-R+prbvh` | PLOC optimised by PRBVH |
//! | `lbvh+rbvh` (any base `+rbvh`) | sequential reinsertion ([`crate::bvh::build::rbvh`]), the paper's reference |
//! | any name given to [`register_external`] | an external builder; `arbor-bench` registers the obvhs crate's presets |
//!
//! Every builder returns a tree with one primitive per leaf; the leaf collapse is applied by the
//! caller, the same for all, so that trees compare by topology and not by leaf policy.

pub mod binned_sah;
pub mod lbvh;
pub mod ploc;
pub mod prbvh;
pub mod rbvh;

use std::fmt;
use std::str::FromStr;
use std::sync::RwLock;
use std::time::{Duration, Instant};

use prbvh::{LockStrategy, PrbvhConfig, PrbvhStats};
use rayon::prelude::*;

use crate::bvh::{Bvh, CollapseConfig, MeshBvh, Tracing, collapse_leaves};
use crate::geometry::{Aabb, Triangle};
use ploc::PlocConfig;
use rbvh::{RbvhConfig, RbvhStats};

/// A builder, optionally followed by an optimiser.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Builder {
    pub base: BaseBuilder,
    pub optimize: Option<Optimizer>,
}

/// What runs after the base builder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Optimizer {
    /// Parallel reinsertion ([`crate::bvh::build::prbvh`]) with these locks.
    Prbvh(LockStrategy),
    /// Sequential reinsertion ([`crate::bvh::build::rbvh`]), the reference.
    Rbvh,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaseBuilder {
    Lbvh,
    BinnedSah,
    /// PLOC with this search radius.
    Ploc(u32),
    /// A builder from outside the library, added by [`register_external`].
    External(&'static ExternalBuilder),
}

/// A builder that another crate adds to the names [`Builder`] parses (the benchmark crate adds
/// its peers this way, so that the library does not depend on them). Its tree must have one
/// primitive per leaf and pass [`crate::bvh::validate`]; it is traced, collapsed and optimised like
/// ours. It takes no optimiser (`NAME+prbvh` is refused), as it is measured as its authors ship it.
#[derive(Debug)]
pub struct ExternalBuilder {
    /// The name `--builder` takes; must not collide with a library builder's.
    pub name: &'static str,
    /// Builds over the triangles, given with their boxes.
    pub build: fn(&[Triangle], &[Aabb]) -> Bvh,
}

impl PartialEq for ExternalBuilder {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
    }
}

impl Eq for ExternalBuilder {}

static EXTERNAL: RwLock<Vec<&'static ExternalBuilder>> = RwLock::new(Vec::new());

/// Adds an external builder to the names [`Builder`] parses, for the rest of the process. A name
/// registered twice keeps its first registration.
pub fn register_external(builder: ExternalBuilder) {
    let mut list = EXTERNAL.write().unwrap_or_else(|e| e.into_inner());
    if !list.iter().any(|b| b.name == builder.name) {
        list.push(Box::leak(Box::new(builder)));
    }
}

fn external(name: &str) -> Option<&'static ExternalBuilder> {
    EXTERNAL.read().unwrap_or_else(|e| e.into_inner()).iter().copied().find(|b| b.name == name)
}

/// The largest radius `ploc-R` accepts.
pub const PLOC_MAX_RADIUS: u32 = 1024;

#[derive(Debug, thiserror::Error)]
#[error("unknown builder `{name}`; known: {known}")]
pub struct UnknownBuilder {
    pub name: String,
    pub known: String,
}

impl Builder {
    /// Every name [`FromStr`] accepts: the library's, then the registered external ones.
    pub fn names() -> Vec<String> {
        let mut v: Vec<String> = [
            "lbvh",
            "lbvh+prbvh",
            "lbvh+prbvh-conservative",
            "lbvh+rbvh",
            "binned-sah",
            "binned-sah+prbvh",
            "ploc",
            "ploc+prbvh",
        ]
        .map(String::from)
        .to_vec();
        v.extend(EXTERNAL.read().unwrap_or_else(|e| e.into_inner()).iter().map(|b| b.name.to_owned()));
        v
    }
}

impl FromStr for Builder {
    type Err = UnknownBuilder;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let unknown = || UnknownBuilder {
            name: s.to_owned(),
            known: Builder::names().join(", ")
                + &format!(
                    "; PLOC with another radius: ploc-R (R from 1 to {PLOC_MAX_RADIUS}); `prbvh` and `rbvh` alone mean lbvh+prbvh and lbvh+rbvh"
                ),
        };
        // The paper's names for its methods, which start from LBVH (section 6).
        let s_full = match s {
            "prbvh" => "lbvh+prbvh",
            "rbvh" => "lbvh+rbvh",
            other => other,
        };
        let (base, optimize) = match s_full.split_once('+') {
            None => (s_full, None),
            Some((b, "prbvh")) => (b, Some(Optimizer::Prbvh(LockStrategy::Aggressive))),
            Some((b, "prbvh-conservative")) => (b, Some(Optimizer::Prbvh(LockStrategy::Conservative))),
            Some((b, "rbvh")) => (b, Some(Optimizer::Rbvh)),
            Some(_) => return Err(unknown()),
        };
        let base = match base {
            "lbvh" => BaseBuilder::Lbvh,
            "binned-sah" => BaseBuilder::BinnedSah,
            "ploc" => BaseBuilder::Ploc(PlocConfig::default().radius as u32),
            b if b.starts_with("ploc-") => match b["ploc-".len()..].parse::<u32>() {
                Ok(r) if (1..=PLOC_MAX_RADIUS).contains(&r) => BaseBuilder::Ploc(r),
                _ => return Err(unknown()),
            },
            b if optimize.is_none() => BaseBuilder::External(external(b).ok_or_else(unknown)?),
            _ => return Err(unknown()),
        };
        Ok(Builder { base, optimize })
    }
}

impl fmt::Display for Builder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.base {
            BaseBuilder::Lbvh => write!(f, "lbvh")?,
            BaseBuilder::BinnedSah => write!(f, "binned-sah")?,
            BaseBuilder::Ploc(r) if r as usize == PlocConfig::default().radius => write!(f, "ploc")?,
            BaseBuilder::Ploc(r) => write!(f, "ploc-{r}")?,
            BaseBuilder::External(b) => write!(f, "{}", b.name)?,
        }
        match self.optimize {
            None => Ok(()),
            Some(Optimizer::Prbvh(LockStrategy::Aggressive)) => write!(f, "+prbvh"),
            Some(Optimizer::Prbvh(LockStrategy::Conservative)) => write!(f, "+prbvh-conservative"),
            Some(Optimizer::Rbvh) => write!(f, "+rbvh"),
        }
    }
}

/// A tree and what making it cost.
#[derive(Clone, Debug)]
pub struct Built {
    /// One primitive per leaf.
    pub bvh: Bvh,
    pub build_time: Duration,
    pub optimize_time: Duration,
    pub prbvh: Option<PrbvhStats>,
    pub rbvh: Option<RbvhStats>,
}

impl Builder {
    /// Builds over `triangles` (whose boxes are `prim_aabbs`). `prbvh` configures the
    /// optimisation step, whose `strategy` and `collapse` this builder overrides.
    pub fn build(&self, triangles: &[Triangle], prim_aabbs: &[Aabb], prbvh: &PrbvhConfig) -> Built {
        let t = Instant::now();
        let mut bvh = match self.base {
            BaseBuilder::Lbvh => lbvh::build(prim_aabbs),
            BaseBuilder::BinnedSah => binned_sah::build(prim_aabbs, &Default::default()),
            BaseBuilder::Ploc(radius) => ploc::build(prim_aabbs, &PlocConfig { radius: radius as usize }),
            BaseBuilder::External(b) => (b.build)(triangles, prim_aabbs),
        };
        let build_time = t.elapsed();
        let mut built =
            Built { bvh: Bvh::default(), build_time, optimize_time: Duration::ZERO, prbvh: None, rbvh: None };
        match self.optimize {
            Some(Optimizer::Prbvh(strategy)) => {
                let config = PrbvhConfig { strategy, collapse: None, ..*prbvh };
                let stats = prbvh::optimize(&mut bvh, &config);
                built.optimize_time = stats.optimize_time;
                built.prbvh = Some(stats);
            }
            Some(Optimizer::Rbvh) => {
                let stats = rbvh::optimize(&mut bvh, &RbvhConfig { costs: prbvh.costs, ..Default::default() });
                built.optimize_time = stats.time;
                built.rbvh = Some(stats);
            }
            None => {}
        }
        built.bvh = bvh;
        built
    }

    /// A mesh's traceable BVH: built over `triangles` with the default PRBVH settings, then the
    /// default leaf collapse, triangles stored in leaf order, traced as `tracing` says.
    pub fn build_mesh(&self, triangles: &[Triangle], tracing: Tracing) -> MeshBvh {
        let prims: Vec<Aabb> = triangles.par_iter().map(Triangle::aabb).collect();
        let built = self.build(triangles, &prims, &PrbvhConfig { collapse: None, ..Default::default() });
        MeshBvh::new(collapse_leaves(&built.bvh, &CollapseConfig::default()), triangles, tracing)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for name in Builder::names() {
            let b: Builder = name.parse().unwrap();
            assert_eq!(b.to_string(), name);
        }
        assert!("lbvh+prbvh+prbvh".parse::<Builder>().is_err());
        assert_eq!("ploc-100+prbvh".parse::<Builder>().unwrap().to_string(), "ploc-100+prbvh");
        assert_eq!("ploc-16".parse::<Builder>().unwrap().to_string(), "ploc");
        assert_eq!("rbvh".parse::<Builder>().unwrap().to_string(), "lbvh+rbvh");
        assert_eq!("prbvh".parse::<Builder>().unwrap().to_string(), "lbvh+prbvh");
        for bad in ["ploc-0", "ploc-x", "ploc-", "ploc-99999"] {
            assert!(bad.parse::<Builder>().is_err(), "{bad}");
        }
        let e = "nope".parse::<Builder>().unwrap_err().to_string();
        assert!(e.contains("unknown builder `nope`") && e.contains("lbvh+prbvh"), "{e}");
    }

    #[test]
    fn an_external_builder_is_parsed_once_registered() {
        assert!("test-external".parse::<Builder>().is_err());
        register_external(ExternalBuilder { name: "test-external", build: |_, prims| lbvh::build(prims) });
        let b: Builder = "test-external".parse().unwrap();
        assert_eq!(b.to_string(), "test-external");
        assert!(Builder::names().contains(&"test-external".to_owned()));
        assert!("test-external+prbvh".parse::<Builder>().is_err(), "external builders take no optimiser");
        let tris = [Triangle::new(glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y); 3];
        let prims: Vec<Aabb> = tris.iter().map(Triangle::aabb).collect();
        assert_eq!(b.build(&tris, &prims, &Default::default()).bvh.prim_ids.len(), 3);
    }
}
