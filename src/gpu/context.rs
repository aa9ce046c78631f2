//! The GPU context: adapter choice, device, pipeline cache, buffers within the adapter's limits.
//!
//! Adapter order: discrete, then integrated, then virtual GPUs; a software adapter (lavapipe,
//! WARP) only when the caller allows it ([`AdapterPolicy::AllowSoftware`]: `--device gpu` and
//! tests), because the CPU path is faster than a software GPU. GL adapters are never taken: they
//! lack 64-bit integers and subgroups, and wgpu falls back to GL silently when the Vulkan driver
//! is missing, which would hide the real problem.
//!
//! Features the kernels can use (`SHADER_INT64`, `SHADER_INT64_ATOMIC_MIN_MAX`, `SUBGROUP`) are
//! requested when the adapter has them; callers that need one check [`GpuContext::features`]
//! and fail with [`GpuError::MissingFeatures`], naming it. Limits are the adapter's own, so that
//! a large scene gets the adapter's largest buffers, and a buffer over a limit is refused by
//! [`GpuContext::storage_buffer`] with the limit's name.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use wgpu::util::DeviceExt;

/// Whether a software adapter may be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterPolicy {
    /// Only a hardware GPU (`render --device auto`: the CPU path beats a software GPU).
    HardwareOnly,
    /// A hardware GPU if there is one, else a software one (`--device gpu`, tests).
    AllowSoftware,
}

/// What can go wrong setting up or using the GPU.
#[derive(Debug, Clone, thiserror::Error)]
pub enum GpuError {
    #[error("no usable GPU adapter (Vulkan, Metal or DX12){}", list(.found))]
    NoAdapter { found: Vec<String> },
    #[error("only a software GPU adapter ({name}) is available, and software adapters were not allowed")]
    SoftwareOnly { name: String },
    #[error("the GPU adapter {adapter} lacks the features {missing}")]
    MissingFeatures { adapter: String, missing: String },
    #[error("requesting a device from {adapter}: {message}")]
    Device { adapter: String, message: String },
    #[error(
        "{what}: {bytes} bytes is over the adapter's {limit_name} of {limit} bytes; split the scene or use the CPU path"
    )]
    BufferTooLarge { what: String, bytes: u64, limit_name: &'static str, limit: u64 },
    #[error("reading back {what} from the GPU: {message}")]
    Readback { what: String, message: String },
    #[error("{0}")]
    Other(String),
}

fn list(found: &[String]) -> String {
    if found.is_empty() { String::new() } else { format!("; found only: {}", found.join(", ")) }
}

/// A device and queue, the adapter they came from, and compiled pipelines by name.
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub features: wgpu::Features,
    pub limits: wgpu::Limits,
    pipelines: Mutex<HashMap<String, wgpu::ComputePipeline>>,
    /// lampshade's radix sorter (the LBVH's), made once: it compiles its own pipelines.
    sorter: Mutex<Option<lampshade::KeyValueSorter>>,
    /// Nanoseconds spent compiling pipelines ([`GpuContext::compile_time`]).
    compile_nanos: AtomicU64,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.describe()).finish_non_exhaustive()
    }
}

/// Features used where present.
fn wanted_features() -> wgpu::Features {
    wgpu::Features::SHADER_INT64 | wgpu::Features::SHADER_INT64_ATOMIC_MIN_MAX | wgpu::Features::SUBGROUP
}

/// Preference of a device type: lower is better; software last.
fn rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

impl GpuContext {
    /// Picks an adapter by [`AdapterPolicy`] and the order in the module docs, and opens a
    /// device on it.
    pub fn new(policy: AdapterPolicy) -> Result<GpuContext, GpuError> {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        descriptor.backends = descriptor_backends();
        let instance = wgpu::Instance::new(descriptor);
        let mut adapters: Vec<wgpu::Adapter> = pollster::block_on(instance.enumerate_adapters(descriptor_backends()))
            .into_iter()
            .filter(|a| a.get_info().backend != wgpu::Backend::Gl)
            .collect();
        adapters.sort_by_key(|a| rank(a.get_info().device_type));
        let names: Vec<String> = adapters.iter().map(|a| describe(&a.get_info())).collect();
        let Some(adapter) = adapters.into_iter().next() else {
            return Err(GpuError::NoAdapter { found: names });
        };
        let info = adapter.get_info();
        if info.device_type == wgpu::DeviceType::Cpu && policy == AdapterPolicy::HardwareOnly {
            return Err(GpuError::SoftwareOnly { name: describe(&info) });
        }
        let features = adapter.features() & wanted_features();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("arbor"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device { adapter: describe(&info), message: e.to_string() })?;
        Ok(GpuContext {
            device,
            queue,
            info,
            features,
            limits,
            pipelines: Mutex::new(HashMap::new()),
            sorter: Mutex::new(None),
            compile_nanos: AtomicU64::new(0),
        })
    }

    /// One context per process, software allowed: what tests and `--device gpu` share, so that
    /// each pipeline compiles once (seconds on lavapipe).
    pub fn shared() -> Result<&'static GpuContext, GpuError> {
        static SHARED: OnceLock<Result<GpuContext, GpuError>> = OnceLock::new();
        SHARED.get_or_init(|| GpuContext::new(AdapterPolicy::AllowSoftware)).as_ref().map_err(Clone::clone)
    }

    /// `name (type, backend)`.
    pub fn describe(&self) -> String {
        describe(&self.info)
    }

    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Fails naming the features in `needed` that this device lacks.
    pub fn require(&self, needed: wgpu::Features) -> Result<(), GpuError> {
        let missing = needed - self.features;
        if missing.is_empty() {
            Ok(())
        } else {
            Err(GpuError::MissingFeatures { adapter: self.describe(), missing: format!("{missing:?}") })
        }
    }

    /// The compute pipeline for `entry` of the shader `source` (cached under `key`, which names
    /// the shader and its variant), its layout derived from what the entry point reads:
    /// compiled once per process.
    pub fn pipeline(&self, key: &str, source: impl FnOnce() -> String, entry: &str) -> wgpu::ComputePipeline {
        self.make_pipeline(key, source, entry, None::<fn() -> wgpu::PipelineLayout>)
    }

    /// [`GpuContext::pipeline`] with the layout `layout` makes (called only when compiling), for
    /// kernels of one shader that share a bind group while reading different bindings.
    pub fn pipeline_with_layout(
        &self,
        key: &str,
        source: impl FnOnce() -> String,
        entry: &str,
        layout: impl FnOnce() -> wgpu::PipelineLayout,
    ) -> wgpu::ComputePipeline {
        self.make_pipeline(key, source, entry, Some(layout))
    }

    fn make_pipeline(
        &self,
        key: &str,
        source: impl FnOnce() -> String,
        entry: &str,
        layout: Option<impl FnOnce() -> wgpu::PipelineLayout>,
    ) -> wgpu::ComputePipeline {
        let full_key = format!("{key}::{entry}");
        let mut cache = self.pipelines.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = cache.get(&full_key) {
            return p.clone();
        }
        let start = Instant::now();
        let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(key),
            source: wgpu::ShaderSource::Wgsl(source().into()),
        });
        let layout = layout.map(|f| f());
        let pipeline = self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(&full_key),
            layout: layout.as_ref(),
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
        cache.insert(full_key, pipeline.clone());
        self.add_compile_time(start.elapsed());
        pipeline
    }

    /// Time this context has spent compiling pipelines, its own and the radix sorter's: a cost
    /// paid once per process, which build times report apart (it can be most of a first GPU
    /// build's time; docs/benchmarks.md, "Compilation").
    pub fn compile_time(&self) -> Duration {
        Duration::from_nanos(self.compile_nanos.load(Ordering::Relaxed))
    }

    fn add_compile_time(&self, d: Duration) {
        self.compile_nanos.fetch_add(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX), Ordering::Relaxed);
    }

    /// Runs `f` with the context's radix sorter, made (and its pipelines compiled) on first use.
    pub fn with_sorter<R>(&self, f: impl FnOnce(&mut lampshade::KeyValueSorter) -> R) -> R {
        let mut sorter = self.sorter.lock().unwrap_or_else(|e| e.into_inner());
        let sorter = sorter.get_or_insert_with(|| {
            let start = Instant::now();
            let made = lampshade::KeyValueSorter::new_for_adapter(&self.device, &self.queue, &self.info);
            self.add_compile_time(start.elapsed());
            made
        });
        f(sorter)
    }

    /// A storage buffer holding `data` (at least 4 bytes, as wgpu requires), usable as a copy
    /// source and destination too. Refused, naming the limit, when over the adapter's largest
    /// storage binding.
    pub fn storage_buffer<T: bytemuck::Pod>(&self, what: &str, data: &[T]) -> Result<wgpu::Buffer, GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.check_size(what, bytes.len() as u64)?;
        let mut padded;
        let contents = if bytes.len() < 4 {
            padded = bytes.to_vec();
            padded.resize(4, 0);
            &padded[..]
        } else {
            bytes
        };
        Ok(self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(what),
            contents,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        }))
    }

    /// An uninitialised (zeroed) storage buffer of `bytes` bytes (at least 4).
    pub fn storage_buffer_zeroed(&self, what: &str, bytes: u64) -> Result<wgpu::Buffer, GpuError> {
        self.check_size(what, bytes)?;
        Ok(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(what),
            size: bytes.max(4).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }))
    }

    /// A uniform buffer holding `value`.
    pub fn uniform_buffer<T: bytemuck::Pod>(&self, what: &str, value: &T) -> wgpu::Buffer {
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(what),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
    }

    fn check_size(&self, what: &str, bytes: u64) -> Result<(), GpuError> {
        let limit = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::BufferTooLarge {
                what: what.to_owned(),
                bytes,
                limit_name: "max_storage_buffer_binding_size",
                limit,
            });
        }
        Ok(())
    }

    /// Copies the first `len` elements of `buffer` back to the host (waits for the GPU).
    pub fn read_buffer<T: bytemuck::Pod>(
        &self,
        what: &str,
        buffer: &wgpu::Buffer,
        len: usize,
    ) -> Result<Vec<T>, GpuError> {
        let bytes = (len * size_of::<T>()) as u64;
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes.next_multiple_of(4),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes.next_multiple_of(4));
        self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        let fail = |message: String| GpuError::Readback { what: what.to_owned(), message };
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| fail(e.to_string()))?;
        rx.recv().map_err(|e| fail(e.to_string()))?.map_err(|e| fail(e.to_string()))?;
        let view = slice.get_mapped_range().map_err(|e| fail(e.to_string()))?;
        let out: Vec<T> = bytemuck::cast_slice(&view[..len * size_of::<T>()]).to_vec();
        drop(view);
        staging.unmap();
        Ok(out)
    }

    /// Waits until the GPU has finished all submitted work.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely()).map(|_| ()).map_err(|e| GpuError::Other(e.to_string()))
    }

    /// A bind group for `pipeline`'s group 0 with each buffer at its binding.
    pub fn bind_group(&self, pipeline: &wgpu::ComputePipeline, bindings: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = bindings
            .iter()
            .map(|&(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Workgroup counts for `items` threads of `WORKGROUP_SIZE`, as a 2D grid when one dimension
    /// would pass the adapter's per-dimension limit (kernels rebuild the linear index from
    /// `num_workgroups`).
    pub fn dispatch_size(&self, items: u32) -> (u32, u32) {
        let groups = items.div_ceil(super::layout::WORKGROUP_SIZE).max(1);
        let max = self.limits.max_compute_workgroups_per_dimension.max(1);
        if groups <= max { (groups, 1) } else { (max, groups.div_ceil(max)) }
    }
}

/// The backends to look at: the environment's `WGPU_BACKEND`, or Vulkan, Metal and DX12.
fn descriptor_backends() -> wgpu::Backends {
    wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY) & !wgpu::Backends::GL
}

fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?})", info.name, info.device_type, info.backend)
}
