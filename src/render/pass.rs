//! One call's worth of rendering, as every device takes it: [`Pass`] says which samples of which
//! pixels ([`Region`]), rendered how (the seed, path depth and time budget of
//! [`RenderSettings`]), carrying on from what (a film of the region's first samples), and who
//! hears of it (progress, and whether to pause). `device::Renderer::render_region` takes it, and
//! hands it on to the GPU's trace (`gpu::trace::render_from`) or drives the CPU's tile loop
//! ([`super::tiles`]) with it.
//!
//! It lives at the render layer, below `device` and `gpu`, so that both read the same struct;
//! what is carried differs by device (a host film for the device, samples left on the GPU for
//! the trace), hence the type parameter.

use super::region::Region;
use crate::scene::RenderSettings;

/// How far a render has come, for a progress bar: `done` of `total` units (pixel rows × samples),
/// and the rays traced so far where the device counts them as it goes (the CPU; 0 on the GPU).
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub done: u64,
    pub total: u64,
    pub rays: u64,
}

/// A pass's settings, region, carried samples and callbacks (module docs).
pub struct Pass<'a, C> {
    /// The seed, the path depth and the time budget (`settings.spp` is not read: the region
    /// says which samples).
    pub settings: &'a RenderSettings,
    /// The rectangle of the image and the sample indices of each of its pixels.
    pub region: Region,
    /// The region's first samples, taken before (a checkpoint, an earlier pass): the pass
    /// carries on from there.
    pub carried: Option<C>,
    /// Hears of every row (CPU) or pass (GPU) done.
    pub progress: &'a (dyn Fn(Progress) + Sync),
    /// Asked between passes with the samples per pixel taken so far (of the region's); yes
    /// returns there, to be carried on later.
    pub pause: &'a (dyn Fn(u32) -> bool + Sync),
    /// Asked often while a pass runs (the CPU: at every pixel; the GPU: between its
    /// submissions); yes abandons the pass at once, its samples dropped, and the render returns
    /// at the last whole pass: what a signal asks, when a pass may take longer than a
    /// scheduler's grace period.
    pub abandon: &'a (dyn Fn() -> bool + Sync),
}

impl<'a, C> Pass<'a, C> {
    /// `region` under `settings`, from scratch, heard by nobody and never paused.
    pub fn new(settings: &'a RenderSettings, region: Region) -> Self {
        Self { settings, region, carried: None, progress: &|_| {}, pause: &|_| false, abandon: &|| false }
    }

    /// The pass carrying on from `carried`.
    pub fn carrying(self, carried: Option<C>) -> Self {
        Self { carried, ..self }
    }

    /// The pass reporting to `progress`.
    pub fn with_progress(self, progress: &'a (dyn Fn(Progress) + Sync)) -> Self {
        Self { progress, ..self }
    }

    /// The pass asking `pause` between passes.
    pub fn with_pause(self, pause: &'a (dyn Fn(u32) -> bool + Sync)) -> Self {
        Self { pause, ..self }
    }

    /// The pass asking `abandon` while it runs.
    pub fn with_abandon(self, abandon: &'a (dyn Fn() -> bool + Sync)) -> Self {
        Self { abandon, ..self }
    }
}
