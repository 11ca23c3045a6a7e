//! The device: a Vulkan adapter with ray queries, opened with the
//! experimental ray-query feature.

use crate::error::GpuError;

/// A wgpu device and queue that can build acceleration structures and run
/// ray queries.
#[derive(Debug)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
}

impl GpuContext {
    /// Opens the first Vulkan adapter with ray queries (high performance
    /// preferred). Without a Vulkan driver, or with one lacking ray queries,
    /// returns an error that says what to install; never panics.
    pub fn new() -> Result<GpuContext, GpuError> {
        pollster::block_on(Self::open())
    }

    async fn open() -> Result<GpuContext, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: None,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::NoAdapter {
                details: e.to_string(),
            })?;
        let info = adapter.get_info();
        let needed = wgpu::Features::EXPERIMENTAL_RAY_QUERY;
        if !adapter.features().contains(needed) {
            return Err(GpuError::NoRayQuery {
                adapter: info.name.clone(),
                driver: format!("{} {}", info.driver, info.driver_info),
            });
        }
        // SAFETY: `ExperimentalFeatures::enabled` is `unsafe` only as an
        // acknowledgement that wgpu's experimental APIs (here: ray queries
        // and acceleration structures) may still have bugs; it has no
        // memory-safety precondition a caller could violate. We use those
        // APIs only through wgpu's validated, safe calls, inside error
        // scopes, and check results against the CPU backend in tests.
        #[allow(unsafe_code)]
        let experimental = unsafe { wgpu::ExperimentalFeatures::enabled() };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("psao-gpu"),
                required_features: needed,
                required_limits: wgpu::Limits::default()
                    .using_acceleration_structure_values(adapter.limits()),
                experimental_features: experimental,
                memory_hints: wgpu::MemoryHints::Performance,
                trace: wgpu::Trace::Off,
            })
            .await
            .map_err(|e| GpuError::Device(e.to_string()))?;
        Ok(GpuContext {
            device,
            queue,
            info,
        })
    }

    /// The adapter's name, backend and driver, for reports.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {} {})",
            self.info.name, self.info.backend, self.info.driver, self.info.driver_info
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

    /// Maps a `MAP_READ` buffer of f32 values once the queue is done and
    /// copies them out.
    pub(crate) fn read_f32(&self, buffer: &wgpu::Buffer) -> Result<Vec<f32>, GpuError> {
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
            bytemuck::cast_slice::<u8, f32>(&view).to_vec()
        };
        buffer.unmap();
        Ok(values)
    }

    /// Waits for submitted work.
    pub(crate) fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::DeviceLost(e.to_string()))
    }
}
