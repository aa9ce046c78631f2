//! Embree 3 as a peer (feature `embree`): Intel's own trees, built over Arbor's triangles, traced
//! by Embree's own traversal (`rtcIntersect1` for closest hits, `rtcOccluded1` for shadow rays).
//! Unlike the obvhs peer, nothing is converted to Arbor's layout: this measures Embree as its
//! authors ship it, trees and traversal together, against Arbor's.
//!
//! Through the `embree` crate's raw FFI (`embree::sys`, Embree 3.13 as Debian's `libembree-dev`
//! gives it), since all a peer needs is a handful of calls. Choices that make Embree's hits
//! comparable with Arbor's:
//! - one triangle geometry whose `primID` is the index into Arbor's triangle slice, so a hit
//!   names the same primitive in both;
//! - `RTC_SCENE_FLAG_ROBUST`, Embree's watertight mode (Arbor's triangle test is watertight);
//! - ray directions as Arbor's rays have them (not normalised), so `t` is in the ray's own
//!   parametrisation, as in Arbor;
//! - `tnear = f32::MIN_POSITIVE`: Arbor accepts `0 < t <= t_max`, Embree `tnear <= t <= tfar`,
//!   and with `tnear = 0` the robust mode accepts a hit at exactly `t = 0` (a ray spawned with a
//!   zero offset hits the triangle it leaves). The smallest *normal* float rather than the
//!   smallest subnormal one, which a flush-to-zero mode would read as 0.
//!
//! What still differs: Embree breaks ties between triangles at the same `t` its own way (Arbor
//! takes the lowest primitive id) and computes `t` with other arithmetic, so a few rays per 10^5
//! that graze a shared edge hit the neighbouring triangle, or miss where Arbor hits.

use std::ffi::CString;
use std::time::{Duration, Instant};

use ::embree::sys;

use arbor::geometry::{Ray, Triangle};

/// Embree's build quality (`RTC_BUILD_QUALITY_*`); the builder names are `embree-low`,
/// `embree-medium` and `embree-high`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// Morton-code build, fastest.
    Low,
    /// Binned SAH, Embree's default.
    Medium,
    /// Binned SAH with spatial splits.
    High,
}

impl Quality {
    pub const ALL: [Quality; 3] = [Quality::Low, Quality::Medium, Quality::High];

    /// The builder name: `embree-low`, `embree-medium`, `embree-high`.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Low => "embree-low",
            Quality::Medium => "embree-medium",
            Quality::High => "embree-high",
        }
    }

    /// The quality a builder name gives, `None` for other names.
    pub fn from_name(name: &str) -> Option<Quality> {
        Quality::ALL.into_iter().find(|q| q.name() == name)
    }

    fn raw(self) -> sys::RTCBuildQuality {
        match self {
            Quality::Low => sys::RTCBuildQuality::LOW,
            Quality::Medium => sys::RTCBuildQuality::MEDIUM,
            Quality::High => sys::RTCBuildQuality::HIGH,
        }
    }
}

/// An Embree call that failed, with Embree's error code.
#[derive(Debug, thiserror::Error)]
pub enum EmbreeError {
    #[error("Embree could not create a device with config `{config}`: {code:?}")]
    Device { config: String, code: sys::RTCError },
    #[error("Embree failed to {what}: {code:?}")]
    Call { what: &'static str, code: sys::RTCError },
    #[error("Embree's 32-bit vertex indices take fewer than (2^32 - 1) / 3 triangles in one geometry, not {0}")]
    TooManyTriangles(usize),
}

/// An Embree device: its thread pool and kernels. Embree 3 sizes its (TBB) thread pool to the
/// largest `threads=` of the devices alive at once, so create one device per thread count, and
/// drop it before timing another.
pub struct Device {
    raw: sys::RTCDevice,
}

// SAFETY: an RTCDevice is a reference-counted handle that Embree's API lets any thread use
// (its calls synchronise internally); `Device` only creates scenes on it and releases it once.
unsafe impl Send for Device {}
// SAFETY: as above; the only calls made through `&Device` (`rtcNewScene`, `rtcNewGeometry`,
// `rtcGetDeviceError`) are thread-safe in Embree 3.
unsafe impl Sync for Device {}

impl Device {
    /// A device whose builds use `threads` threads, with the best kernels the CPU has.
    pub fn new(threads: usize) -> Result<Device, EmbreeError> {
        let config = format!("threads={}", threads.max(1));
        let c_config = CString::new(config.clone()).expect("the config has no NUL byte");
        // SAFETY: `c_config` is a NUL-terminated string that outlives the call, which only
        // reads it.
        let raw = unsafe { sys::rtcNewDevice(c_config.as_ptr()) };
        if raw.is_null() {
            // SAFETY: a null device asks for the error of the last failed device creation.
            let code = unsafe { sys::rtcGetDeviceError(std::ptr::null_mut()) };
            return Err(EmbreeError::Device { config, code });
        }
        Ok(Device { raw })
    }

    /// The first error recorded on this device since the last check, as `what` failing.
    fn check(&self, what: &'static str) -> Result<(), EmbreeError> {
        // SAFETY: `self.raw` is a live device (released only in `drop`).
        match unsafe { sys::rtcGetDeviceError(self.raw) } {
            sys::RTCError::NONE => Ok(()),
            code => Err(EmbreeError::Call { what, code }),
        }
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: `self.raw` holds the reference `rtcNewDevice` returned, released once here;
        // scenes built on it hold references of their own.
        unsafe { sys::rtcReleaseDevice(self.raw) };
    }
}

/// A committed Embree scene over one triangle mesh, ready to trace from any thread.
pub struct Scene {
    raw: sys::RTCScene,
    /// The device's handle, retained while the scene lives.
    device: sys::RTCDevice,
}

// SAFETY: a committed scene is immutable; Embree 3 documents `rtcIntersect1` and `rtcOccluded1`
// on a committed scene as safe to call from any number of threads at once, and `Scene` offers
// no call that modifies it. Its release (in `drop`) may happen on any thread.
unsafe impl Send for Scene {}
// SAFETY: as above.
unsafe impl Sync for Scene {}

impl Scene {
    /// Builds Embree's tree over `triangles` at `quality`, with the robust flag; returns the
    /// scene and the time of the build itself (`rtcCommitScene`). The copy of the triangles into
    /// Embree's buffers is not timed, as Arbor's builders get their primitives' boxes for free.
    pub fn build(device: &Device, triangles: &[Triangle], quality: Quality) -> Result<(Scene, Duration), EmbreeError> {
        // Embree's indices and `primID` are u32, `u32::MAX` meaning none.
        if 3 * triangles.len() as u64 >= u32::MAX as u64 {
            return Err(EmbreeError::TooManyTriangles(triangles.len()));
        }
        // SAFETY: the device is live; a null scene is checked below.
        let raw = unsafe { sys::rtcNewScene(device.raw) };
        if raw.is_null() {
            device.check("create a scene")?;
            return Err(EmbreeError::Call { what: "create a scene", code: sys::RTCError::UNKNOWN });
        }
        // SAFETY: the device is live; the scene keeps its own reference to it, and this one is
        // the scene's to release in `drop`.
        unsafe { sys::rtcRetainDevice(device.raw) };
        // From here `scene` releases both on every return.
        let scene = Scene { raw, device: device.raw };
        // SAFETY: `scene.raw` is a live scene not yet committed, which these set up.
        unsafe {
            sys::rtcSetSceneBuildQuality(scene.raw, quality.raw());
            sys::rtcSetSceneFlags(scene.raw, sys::RTCSceneFlags::ROBUST);
        }
        if !triangles.is_empty() {
            scene.attach_triangles(device, triangles)?;
        }
        let t = Instant::now();
        // SAFETY: the scene is live, with its one geometry committed and attached.
        unsafe { sys::rtcCommitScene(scene.raw) };
        let time = t.elapsed();
        device.check("build the scene")?;
        Ok((scene, time))
    }

    /// One triangle geometry over `triangles`, each with its own three vertices (a triangle soup,
    /// as Arbor's `&[Triangle]` is), so that `primID` is the index into `triangles`.
    fn attach_triangles(&self, device: &Device, triangles: &[Triangle]) -> Result<(), EmbreeError> {
        // SAFETY: the device is live; a null geometry is checked below.
        let geometry = unsafe { sys::rtcNewGeometry(device.raw, sys::RTCGeometryType::TRIANGLE) };
        if geometry.is_null() {
            device.check("create a triangle geometry")?;
            return Err(EmbreeError::Call { what: "create a triangle geometry", code: sys::RTCError::UNKNOWN });
        }
        let n = triangles.len();
        // SAFETY: `geometry` is live. Embree allocates each buffer for the item count and stride
        // given (with the padding its SIMD loads need) and returns it, or null on failure.
        let (vertices, indices) = unsafe {
            (
                sys::rtcSetNewGeometryBuffer(
                    geometry,
                    sys::RTCBufferType::VERTEX,
                    0,
                    sys::RTCFormat::FLOAT3,
                    3 * size_of::<f32>(),
                    3 * n,
                ) as *mut f32,
                sys::rtcSetNewGeometryBuffer(
                    geometry,
                    sys::RTCBufferType::INDEX,
                    0,
                    sys::RTCFormat::UINT3,
                    3 * size_of::<u32>(),
                    n,
                ) as *mut u32,
            )
        };
        let result = if vertices.is_null() || indices.is_null() {
            device.check("allocate the triangle buffers").and(Err(EmbreeError::Call {
                what: "allocate the triangle buffers",
                code: sys::RTCError::OUT_OF_MEMORY,
            }))
        } else {
            // SAFETY: Embree allocated `vertices` for 9n floats and `indices` for 3n u32s, both
            // aligned for their type (Embree aligns buffers to 16 bytes), and nothing else holds
            // them until the geometry is committed.
            let (vertices, indices) = unsafe {
                (std::slice::from_raw_parts_mut(vertices, 9 * n), std::slice::from_raw_parts_mut(indices, 3 * n))
            };
            for (k, t) in triangles.iter().enumerate() {
                vertices[9 * k..9 * k + 9]
                    .copy_from_slice(&[t.v0.x, t.v0.y, t.v0.z, t.v1.x, t.v1.y, t.v1.z, t.v2.x, t.v2.y, t.v2.z]);
            }
            for (i, v) in indices.iter_mut().enumerate() {
                // `i < 3n < 2^32 - 1`, checked by `build`.
                *v = i as u32;
            }
            // SAFETY: `geometry` is live with its buffers filled; attaching gives the scene its
            // own reference, so the one `rtcNewGeometry` returned is released here.
            unsafe {
                sys::rtcCommitGeometry(geometry);
                sys::rtcAttachGeometry(self.raw, geometry);
            }
            device.check("attach the triangle geometry")
        };
        // SAFETY: the reference `rtcNewGeometry` returned, released once; a scene it is attached
        // to holds its own.
        unsafe { sys::rtcReleaseGeometry(geometry) };
        result
    }

    /// The closest hit with `0 < t <= t_max` (as [`arbor::bvh::MeshBvh::closest_hit`] takes
    /// it): the triangle's index and `t`, in the ray's own parametrisation.
    pub fn closest_hit(&self, ray: &Ray, t_max: f32) -> Option<(u32, f32)> {
        let mut ray_hit = sys::RTCRayHit {
            ray: rtc_ray(ray, t_max),
            hit: sys::RTCHit {
                Ng_x: 0.0,
                Ng_y: 0.0,
                Ng_z: 0.0,
                u: 0.0,
                v: 0.0,
                primID: INVALID_ID,
                geomID: INVALID_ID,
                instID: [INVALID_ID],
            },
        };
        let mut context = intersect_context();
        // SAFETY: the scene is committed (by `build`) and alive for `&self`; `context` and
        // `ray_hit` are valid, suitably aligned values on this stack that Embree only uses for
        // the call (it is thread-safe on a committed scene).
        unsafe { sys::rtcIntersect1(self.raw, &mut context, &mut ray_hit) };
        (ray_hit.hit.geomID != INVALID_ID).then_some((ray_hit.hit.primID, ray_hit.ray.tfar))
    }

    /// Whether anything is hit with `0 < t <= t_max` (a shadow ray).
    pub fn any_hit(&self, ray: &Ray, t_max: f32) -> bool {
        let mut rtc = rtc_ray(ray, t_max);
        let mut context = intersect_context();
        // SAFETY: as in `closest_hit`.
        unsafe { sys::rtcOccluded1(self.raw, &mut context, &mut rtc) };
        // Embree marks an occluded ray by setting `tfar` to -inf.
        rtc.tfar == f32::NEG_INFINITY
    }
}

impl Drop for Scene {
    fn drop(&mut self) {
        // SAFETY: both references were taken by `build` and are released once here, the scene
        // first, as it was built on the device.
        unsafe {
            sys::rtcReleaseScene(self.raw);
            sys::rtcReleaseDevice(self.device);
        }
    }
}

/// `RTC_INVALID_GEOMETRY_ID`.
const INVALID_ID: u32 = u32::MAX;

/// Arbor's ray as Embree's, with `tnear` just above 0 (see the module docs).
fn rtc_ray(ray: &Ray, t_max: f32) -> sys::RTCRay {
    sys::RTCRay {
        org_x: ray.origin.x,
        org_y: ray.origin.y,
        org_z: ray.origin.z,
        tnear: f32::MIN_POSITIVE,
        dir_x: ray.dir.x,
        dir_y: ray.dir.y,
        dir_z: ray.dir.z,
        time: 0.0,
        tfar: t_max,
        mask: u32::MAX,
        id: 0,
        flags: 0,
    }
}

/// What the C API's inline `rtcInitIntersectContext` sets (the crate's FFI has no binding for an
/// inline function): incoherent rays, no filter, no instance.
fn intersect_context() -> sys::RTCIntersectContext {
    sys::RTCIntersectContext { flags: sys::RTCIntersectContextFlags::INCOHERENT, filter: None, instID: [INVALID_ID] }
}
