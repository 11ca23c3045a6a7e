//! The device: opened here (a Vulkan adapter with ray queries for the
//! server half, any adapter for the client half) or handed in by a
//! renderer, and the helpers every pass uses (error scopes, buffers,
//! pipelines, readback, timing).

use std::time::Duration;

use crate::error::GpuError;

/// A compute-stage uniform buffer binding.
pub(crate) fn uniform_layout(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A compute-stage storage buffer binding.
pub(crate) fn storage_layout(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Wall-clock times of one image pass on the GPU.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PassTimes {
    /// From submitting the passes, with their inputs already on the
    /// device, until they finished: what a renderer that keeps its
    /// G-buffer on the GPU pays.
    pub passes: Duration,
    /// Uploading the inputs, the passes and reading the image back.
    pub total: Duration,
}

/// A wgpu device and its queue, opened here ([`new`](Self::new) with ray
/// queries for the server half, [`new_client`](Self::new_client) without)
/// or handed in by a renderer ([`from_device`](Self::from_device)).
///
/// The client half ([`GpuMirror`](crate::GpuMirror),
/// [`GpuReconstruct`](crate::GpuReconstruct)) and the SAO baseline need
/// only compute shaders and storage buffers
/// ([`CLIENT_FEATURES`](Self::CLIENT_FEATURES) within
/// [`client_limits`](Self::client_limits)); the server half (acceleration
/// structures, point AO) also needs
/// [`SERVER_FEATURES`](Self::SERVER_FEATURES) and says so with
/// [`GpuError::NoRayQuery`] on a device without them.
#[derive(Debug)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
}

/// Adapter types in the order they are preferred: a discrete GPU first,
/// then an integrated one, then anything else (lavapipe is a CPU device).
fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

impl GpuContext {
    /// The wgpu features the client half and the SAO baseline need: none
    /// beyond WebGPU's core (compute shaders, storage buffers).
    pub const CLIENT_FEATURES: wgpu::Features = wgpu::Features::empty();

    /// The wgpu features the server half needs: ray queries and
    /// acceleration structures (wgpu's experimental ray queries, which
    /// also need `wgpu::ExperimentalFeatures` enabled when the device is
    /// requested).
    pub const SERVER_FEATURES: wgpu::Features = wgpu::Features::EXPERIMENTAL_RAY_QUERY;

    /// The limits the client half and the SAO baseline need: wgpu's
    /// downlevel defaults (what WebGPU and most mobile GPUs offer) with
    /// eight storage buffers per shader stage, WebGPU's default (the
    /// reconstruction pass binds the mirror's four and the G-buffer's
    /// four). Larger limits let larger mirrors and images fit
    /// (`max_storage_buffer_binding_size` bounds the bytes of one mirror
    /// array and of one image).
    pub fn client_limits() -> wgpu::Limits {
        wgpu::Limits {
            max_storage_buffers_per_shader_stage: 8,
            ..wgpu::Limits::downlevel_defaults()
        }
    }

    /// Opens a Vulkan adapter with ray queries, for both halves (a
    /// discrete GPU preferred, then an integrated one, then a CPU driver
    /// such as lavapipe). Without a Vulkan driver, or with one lacking ray
    /// queries, returns an error that says what to install; never panics.
    pub fn new() -> Result<GpuContext, GpuError> {
        pollster::block_on(Self::open(true))
    }

    /// Opens the preferred Vulkan adapter, ray queries or not, for the
    /// client half and the SAO baseline only (this crate builds wgpu with
    /// Vulkan alone; a renderer on another backend hands in its device
    /// with [`from_device`](Self::from_device), its wgpu's backends being
    /// its own).
    pub fn new_client() -> Result<GpuContext, GpuError> {
        pollster::block_on(Self::open(false))
    }

    /// Wraps a renderer's own device and queue (clones of them: wgpu's
    /// handles are shared). The client half needs no feature
    /// ([`CLIENT_FEATURES`](Self::CLIENT_FEATURES)); the server half works
    /// if the device was requested with
    /// [`SERVER_FEATURES`](Self::SERVER_FEATURES). Every call of this crate
    /// runs inside its own error scopes, so none of its errors reach the
    /// renderer's uncaptured-error handler, which is left as it is.
    ///
    /// Fails with [`GpuError::Limits`], naming the first limit, when the
    /// device's limits are below [`client_limits`](Self::client_limits).
    pub fn from_device(device: wgpu::Device, queue: wgpu::Queue) -> Result<GpuContext, GpuError> {
        let mut short = None;
        Self::client_limits().check_limits_with_fail_fn(
            &device.limits(),
            true,
            |what, needed, limit| {
                short = Some(GpuError::Limits {
                    what,
                    needed,
                    limit,
                })
            },
        );
        match short {
            Some(e) => Err(e),
            None => Ok(GpuContext { device, queue }),
        }
    }

    async fn open(ray_queries: bool) -> Result<GpuContext, GpuError> {
        let backends = wgpu::Backends::VULKAN;
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapters = instance.enumerate_adapters(backends).await;
        if adapters.is_empty() {
            return Err(GpuError::NoAdapter {
                details: "the Vulkan loader found no device".into(),
            });
        }
        let needed = if ray_queries {
            Self::SERVER_FEATURES
        } else {
            Self::CLIENT_FEATURES
        };
        let client = Self::client_limits();
        let usable = |a: &&wgpu::Adapter| {
            a.features().contains(needed)
                && a.get_downlevel_capabilities()
                    .flags
                    .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
                && client.check_limits(&a.limits())
        };
        let Some(adapter) = adapters
            .iter()
            .filter(usable)
            .min_by_key(|a| rank(a.get_info().device_type))
        else {
            if !ray_queries {
                let info = adapters[0].get_info();
                return Err(GpuError::NoAdapter {
                    details: format!(
                        "`{}` ({:?}) lacks compute shaders or the client limits",
                        info.name, info.backend
                    ),
                });
            }
            let info = adapters[0].get_info();
            return Err(GpuError::NoRayQuery {
                adapter: info.name.clone(),
                driver: format!("{} {}", info.driver, info.driver_info),
            });
        };
        // SAFETY: `ExperimentalFeatures::enabled` is `unsafe` because wgpu's
        // experimental APIs (ray queries, acceleration structures) may still
        // hit undefined behaviour through otherwise safe calls when used
        // outside what wgpu validates. This crate stays inside it: scenes
        // are validated before upload (`Scene::validate`: indices below the
        // vertex count, finite vertices), a skinned BLAS is rebuilt only
        // from the same number of vertices it was created with (checked in
        // `GpuScene::place`), every BLAS lives as long as the `GpuScene`
        // whose TLAS refers to it and none is compacted, and ray queries run
        // only in the compute passes of this crate, whose results the tests
        // compare with the CPU backend. Without ray queries nothing
        // experimental is enabled.
        let experimental = if ray_queries {
            #[allow(unsafe_code)]
            unsafe {
                wgpu::ExperimentalFeatures::enabled()
            }
        } else {
            wgpu::ExperimentalFeatures::disabled()
        };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("psao-gpu"),
                required_features: needed,
                // All the adapter offers: larger buffers and bindings than
                // wgpu's portable defaults.
                required_limits: adapter.limits(),
                experimental_features: experimental,
                memory_hints: wgpu::MemoryHints::Performance,
                trace: wgpu::Trace::Off,
            })
            .await
            .map_err(|e| GpuError::Device(e.to_string()))?;
        // Errors outside an error scope would panic in wgpu's default
        // handler; every call that can fail runs inside `checked`, and
        // anything else is logged rather than aborting the process.
        device.on_uncaptured_error(std::sync::Arc::new(|e: wgpu::Error| {
            eprintln!("psao-gpu: uncaptured GPU error: {e}");
        }));
        Self::from_device(device, queue)
    }

    /// Whether the device was opened with ray queries
    /// ([`SERVER_FEATURES`](Self::SERVER_FEATURES)), which the server half
    /// needs.
    pub fn has_ray_queries(&self) -> bool {
        self.device.features().contains(Self::SERVER_FEATURES)
    }

    /// [`GpuError::NoRayQuery`] unless the device has ray queries.
    #[cfg_attr(not(feature = "server"), allow(dead_code))]
    pub(crate) fn require_ray_queries(&self) -> Result<(), GpuError> {
        if self.has_ray_queries() {
            return Ok(());
        }
        let info = self.device.adapter_info();
        Err(GpuError::NoRayQuery {
            adapter: info.name,
            driver: format!(
                "{} {} (device opened without ray queries)",
                info.driver, info.driver_info
            ),
        })
    }

    /// The adapter's name, backend and driver, for reports.
    pub fn describe(&self) -> String {
        let info = self.device.adapter_info();
        format!(
            "{} ({:?}, {} {})",
            info.name, info.backend, info.driver, info.driver_info
        )
    }

    /// Runs `f` inside a validation and an out-of-memory error scope and
    /// turns what they caught into [`GpuError::Rejected`] naming `what`.
    pub(crate) fn checked<R>(
        &self,
        what: &'static str,
        f: impl FnOnce() -> R,
    ) -> Result<R, GpuError> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let r = f();
        let v = pollster::block_on(validation.pop());
        let o = pollster::block_on(oom.pop());
        match v.or(o) {
            Some(e) => Err(GpuError::Rejected {
                what,
                details: e.to_string(),
            }),
            None => Ok(r),
        }
    }

    /// A buffer holding `bytes` (padded to 16 bytes: wgpu refuses empty
    /// bindings, and to a multiple of 4). Call inside
    /// [`checked`](Self::checked): unlike wgpu's `create_buffer_init`,
    /// which panics when the buffer cannot be made (out of memory, past a
    /// limit), this leaves that to the error scope.
    pub(crate) fn buffer_with(
        &self,
        label: &str,
        bytes: &[u8],
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        let size = (bytes.len() as u64).max(16).next_multiple_of(4);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: true,
        });
        // No mapping means the buffer was not made: the error scope has
        // the reason.
        if let Ok(mut view) = buffer.get_mapped_range_mut(..) {
            view.slice(..bytes.len()).copy_from_slice(bytes);
        }
        buffer.unmap();
        buffer
    }

    /// A uniform buffer holding `value`. Call inside
    /// [`checked`](Self::checked).
    pub(crate) fn uniform<T: bytemuck::Pod>(&self, label: &str, value: &T) -> wgpu::Buffer {
        self.buffer_with(
            label,
            bytemuck::bytes_of(value),
            wgpu::BufferUsages::UNIFORM,
        )
    }

    /// The compute pipeline of `source`'s `main` with `groups` as its bind
    /// group layouts, in order. Call inside [`checked`](Self::checked).
    pub(crate) fn compute_pipeline(
        &self,
        label: &str,
        source: &str,
        groups: &[&wgpu::BindGroupLayout],
    ) -> wgpu::ComputePipeline {
        self.compute_pipeline_at(label, source, "main", groups)
    }

    /// The compute pipeline of `source`'s entry point `entry`, as
    /// [`compute_pipeline`](Self::compute_pipeline).
    pub(crate) fn compute_pipeline_at(
        &self,
        label: &str,
        source: &str,
        entry: &str,
        groups: &[&wgpu::BindGroupLayout],
    ) -> wgpu::ComputePipeline {
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let layouts: Vec<Option<&wgpu::BindGroupLayout>> =
            groups.iter().map(|g| Some(*g)).collect();
        let pl = self
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &layouts,
                immediate_size: 0,
            });
        self.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&pl),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
    }

    /// A zeroed storage buffer of `bytes` (at least 16) that a pass writes
    /// and that can be copied out.
    pub(crate) fn storage_out(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    }

    /// Workgroups for `n` invocations of `workgroup` threads: (per row,
    /// rows), rows past the device's per-dimension limit.
    pub(crate) fn grid(&self, n: usize, workgroup: u32) -> (u32, u32) {
        let groups = (n as u32).div_ceil(workgroup).max(1);
        let per_row = groups.min(
            self.device
                .limits()
                .max_compute_workgroups_per_dimension
                .max(1),
        );
        (per_row, groups.div_ceil(per_row))
    }

    /// Records a compute pass of `pipeline` with `groups` bound in order
    /// over `grid` workgroups into `enc`.
    pub(crate) fn record_pass(
        enc: &mut wgpu::CommandEncoder,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        groups: &[&wgpu::BindGroup],
        grid: (u32, u32),
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes: None,
        });
        pass.set_pipeline(pipeline);
        for (i, g) in groups.iter().enumerate() {
            pass.set_bind_group(i as u32, *g, &[]);
        }
        pass.dispatch_workgroups(grid.0, grid.1, 1);
    }

    /// A command encoder.
    pub(crate) fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    /// A mappable buffer of `bytes` (at least 16) to copy results into.
    pub(crate) fn readback(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(16),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Maps a `MAP_READ` buffer of f32 values once the queue is done and
    /// copies them out.
    pub(crate) fn read_f32(&self, buffer: &wgpu::Buffer) -> Result<Vec<f32>, GpuError> {
        self.read::<f32>(buffer)
    }

    /// Maps a `MAP_READ` buffer once the queue is done and copies its
    /// values out.
    pub(crate) fn read<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        let slice = buffer.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        let rejected = |e: String| GpuError::Rejected {
            what: "readback",
            details: e,
        };
        rx.recv()
            .map_err(|e| GpuError::DeviceLost(e.to_string()))?
            .map_err(|e| rejected(e.to_string()))?;
        let values = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| rejected(e.to_string()))?;
            bytemuck::pod_collect_to_vec::<u8, T>(&view)
        };
        buffer.unmap();
        Ok(values)
    }

    /// Runs recorded passes alone and times them: first flushes the
    /// uploads made at buffer creation (they go out with the next
    /// submission), then submits `commands` and waits, then reads the
    /// first `len` f32 values of `out` back. Returns them with the passes'
    /// time and the time since `start`.
    pub(crate) fn timed_passes(
        &self,
        commands: wgpu::CommandBuffer,
        out: &wgpu::Buffer,
        len: usize,
        start: std::time::Instant,
    ) -> Result<(Vec<f32>, PassTimes), GpuError> {
        self.queue.submit(None);
        self.wait()?;
        let submitted = std::time::Instant::now();
        self.queue.submit(Some(commands));
        self.wait()?;
        let passes = submitted.elapsed();
        let readback = self.checked("readback", || {
            let readback = self.readback("psao-gpu readback", out.size());
            let mut enc = self.encoder("psao-gpu readback");
            enc.copy_buffer_to_buffer(out, 0, &readback, 0, out.size());
            self.queue.submit(Some(enc.finish()));
            readback
        })?;
        let mut values = self.read_f32(&readback)?;
        values.truncate(len);
        Ok((
            values,
            PassTimes {
                passes,
                total: start.elapsed(),
            },
        ))
    }

    /// Waits for submitted work.
    pub(crate) fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::DeviceLost(e.to_string()))
    }
}
