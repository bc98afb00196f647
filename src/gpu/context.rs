//! The GPU device, its queue, and the compiled kernels.

use super::buffers::ParamSlots;
use super::kernels::Kernels;
use crate::{Error, Result};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// A headless wgpu device for compute work, with every kernel compiled once.
///
/// Creating one is expensive (adapter discovery, device creation, shader compilation: tens to hundreds of
/// milliseconds): make one per application and share it (`Clone` is cheap). Honours `WGPU_BACKEND`,
/// `WGPU_ADAPTER_NAME` and `WGPU_POWER_PREF` like wgpu's own tools.
/// It connects to no display server: on a headless machine, creating one prints nothing.
///
/// ```no_run
/// match kinetrace::gpu::GpuContext::new() {
///     Ok(gpu) => println!("running on {}", gpu.adapter_name()),
///     Err(e) => eprintln!("{e}; using the CPU path"),
/// }
/// ```
#[derive(Clone)]
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    pub(crate) kernels: Arc<Kernels>,
    /// The level slots every mesh's per-level passes share ([`ParamSlots::passes`]).
    pub(crate) passes: Arc<ParamSlots>,
    pub(crate) staging: Arc<super::buffers::StagingPool>,
    info: wgpu::AdapterInfo,
    timestamps: bool,
    /// Running totals of uploads, read-backs, submissions and blocking waits.
    counters: Arc<CounterCells>,
    /// The first device error of a submission not yet reported by [`wait`](Self::wait) or a read-back.
    failure: Arc<std::sync::Mutex<Option<String>>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.info.name)
            .finish_non_exhaustive()
    }
}

/// Set to `1` to let `TraceMode::GpuWhenAvailable` accept a software adapter (see [`software_allowed`]).
pub const ALLOW_SOFTWARE_ENV: &str = "KINETRACE_ALLOW_SOFTWARE_GPU";

/// How a [`GpuContext`] picks its adapter and which limits it asks for.
#[derive(Clone, Debug, Default)]
pub struct GpuOptions {
    /// Refuse software adapters (wgpu's [`DeviceType::Cpu`](wgpu::DeviceType::Cpu): Mesa's llvmpipe and
    /// lavapipe, Microsoft's WARP): they run kernels on the CPU cores, typically several times slower than
    /// the crate's CPU paths on the same cores, so "a GPU when there is one" should not mean them. Off by
    /// default (tests and CI machines without a GPU run on lavapipe); `TraceMode::GpuWhenAvailable` sets it
    /// unless [`software_allowed`].
    pub hardware_only: bool,
    /// Limits to request instead of the adapter's own; each must be within the adapter's, or creation fails
    /// with [`Error::NoGpu`]. Small limits exercise the paths that split work over several dispatches or
    /// refuse it with an [`Error`]; `None` (the default) asks for everything the adapter offers.
    pub limits: Option<wgpu::Limits>,
}

/// Whether a software adapter is acceptable where a GPU is optional: when the configuration says so
/// (`option`) or [`ALLOW_SOFTWARE_ENV`] is `1` (`env` is its value, if set).
pub fn software_allowed(option: bool, env: Option<&str>) -> bool {
    option || env == Some("1")
}

/// Whether an adapter may be used: any hardware adapter, a software one ([`DeviceType::Cpu`]) only when
/// allowed.
///
/// [`DeviceType::Cpu`]: wgpu::DeviceType::Cpu
pub fn adapter_accepted(info: &wgpu::AdapterInfo, allow_software: bool) -> bool {
    info.device_type != wgpu::DeviceType::Cpu || allow_software
}

/// The adapter `WGPU_ADAPTER_NAME` / `WGPU_POWER_PREF` pick on `instance` when it is accepted, else the
/// first accepted one the instance lists. `Ok(None)` when the instance has no adapter at all, `Err` when it
/// has only refused (software) ones.
async fn pick_adapter(
    instance: &wgpu::Instance,
    allow_software: bool,
) -> Result<Option<wgpu::Adapter>> {
    if let Ok(adapter) = wgpu::util::initialize_adapter_from_env_or_default(instance, None).await
        && adapter_accepted(&adapter.get_info(), allow_software)
    {
        return Ok(Some(adapter));
    }
    let adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
    if let Some(adapter) = adapters
        .iter()
        .find(|a| adapter_accepted(&a.get_info(), allow_software))
    {
        return Ok(Some(adapter.clone()));
    }
    match adapters.first() {
        None => Ok(None),
        Some(refused) => Err(Error::NoGpu(format!(
            "only the software adapter {} was found; set {ALLOW_SOFTWARE_ENV}=1 to use it",
            refused.get_info().name
        ))),
    }
}

impl GpuContext {
    /// Finds an adapter, software ones included, and creates a device ([`GpuOptions::default`]).
    /// [`Error::NoGpu`] when there is none: callers fall back to the CPU path (and should say so once in
    /// their log).
    pub fn new() -> Result<Self> {
        Self::with_options(&GpuOptions::default())
    }

    /// [`new`](Self::new) with options: refuse software adapters, request particular limits. Logs the
    /// adapter chosen once, at `info` level.
    pub fn with_options(options: &GpuOptions) -> Result<Self> {
        pollster::block_on(Self::new_async(options))
    }

    async fn new_async(options: &GpuOptions) -> Result<Self> {
        let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        let allow_software = !options.hardware_only;
        // The headless Vulkan instance first; when it lists no adapter, wgpu's ordinary instance with every
        // back end the environment allows (GL, …), which may print the display warnings but finds what exists.
        let headless = match headless_vulkan(&desc) {
            Some(instance) => pick_adapter(&instance, allow_software).await?,
            None => None,
        };
        let adapter = match headless {
            Some(adapter) => adapter,
            None => pick_adapter(&wgpu::Instance::new(desc), allow_software)
                .await?
                .ok_or_else(|| Error::NoGpu("no GPU adapter found".into()))?,
        };
        let info = adapter.get_info();
        log::info!(
            "kinetrace: GPU adapter {} ({:?}, {:?})",
            info.name,
            info.device_type,
            info.backend
        );
        // Passthrough SPIR-V lets the kernels forbid floating-point contraction (see `precise`).
        let wanted = wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::PASSTHROUGH_SHADERS;
        let features = adapter.features() & wanted;
        // Ask for what the adapter can do (big meshes need big storage buffers) unless told otherwise.
        let limits = options.limits.clone().unwrap_or_else(|| adapter.limits());
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("kinetrace"),
                required_features: features,
                required_limits: limits,
                ..Default::default()
            })
            .await
            .map_err(|e| Error::NoGpu(format!("{} ({:?}): {e}", info.name, info.backend)))?;
        // Shader or pipeline errors become an Error, not a panic of wgpu's default error handler.
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let kernels = Arc::new(Kernels::new(&device));
        if let Some(e) = scope.pop().await {
            return Err(Error::Gpu(format!(
                "compiling the kernels on {}: {e}",
                info.name
            )));
        }
        let passes = Arc::new(ParamSlots::passes(&device, &queue));
        let ctx = Self {
            device,
            queue,
            kernels,
            passes,
            staging: Default::default(),
            info,
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
            failure: Default::default(),
            counters: Default::default(),
        };
        ctx.count_allocated(ctx.passes.memory_bytes());
        Ok(ctx)
    }

    /// GPU bytes every tree on this device shares: the pass slots its builds' radix sorts read their
    /// digit from (2 KiB, made with the context). Count them once per device in a bytes-per-triangle
    /// figure, beside each tree's own [`GpuMeshBvh::memory_bytes`](super::GpuMeshBvh::memory_bytes).
    pub fn shared_tree_bytes(&self) -> u64 {
        self.passes.memory_bytes()
    }

    /// The adapter's name, e.g. "NVIDIA H100" or "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub fn adapter_name(&self) -> &str {
        &self.info.name
    }

    /// The device's limits (what was requested: the adapter's own unless [`GpuOptions::limits`] said
    /// otherwise).
    pub fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }

    /// Everything wgpu says about the adapter (device type, vendor, back end, driver).
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// Backend and driver, for logs, and whether the kernels are free of contraction.
    pub fn adapter_details(&self) -> String {
        format!(
            "{:?}, {} {}{}",
            self.info.backend,
            self.info.driver,
            self.info.driver_info,
            if self.contraction_free() {
                ", kernels without contraction"
            } else {
                ", kernels may contract"
            }
        )
    }

    /// Whether every kernel was compiled without floating-point contraction, so that its arithmetic
    /// rounds as the CPU's does on any driver (Vulkan: passthrough SPIR-V, see the `gpu` module docs).
    /// Where false (Metal, DX12, or a Vulkan driver without passthrough), a driver that fuses multiplies
    /// and adds may answer rays through shared edges and build trees differently from the CPU.
    pub fn contraction_free(&self) -> bool {
        self.kernels.contraction_free
    }

    /// Whether the device can time passes with timestamp queries.
    pub fn has_timestamps(&self) -> bool {
        self.timestamps
    }

    /// Workgroup counts `(x, y)` for `threads` invocations of `group` each, folded into y past the device's
    /// `max_compute_workgroups_per_dimension` (kernels recover the linear index from `num_workgroups`).
    /// Inputs are checked against [`check_threads`](Self::check_threads) where they enter, so y is within
    /// the limit too.
    pub(crate) fn groups(&self, threads: u32, group: u32) -> (u32, u32) {
        let max = self.max_groups();
        let n = threads.div_ceil(group).max(1);
        if n <= max {
            (n, 1)
        } else {
            (max, n.div_ceil(max))
        }
    }

    /// The device's `max_compute_workgroups_per_dimension`.
    pub(crate) fn max_groups(&self) -> u32 {
        self.device.limits().max_compute_workgroups_per_dimension
    }

    /// Refuses, with [`Error::Gpu`], `threads` invocations of `group` that even an (x, y) dispatch at the
    /// device's limit per dimension cannot cover.
    pub(crate) fn check_threads(&self, what: &str, threads: u64, group: u32) -> Result<()> {
        let max = self.max_groups() as u64;
        let capacity = max * max * group as u64;
        if threads > capacity {
            return Err(Error::Gpu(format!(
                "{what}: {threads} invocations exceed the {capacity} this device dispatches \
                 ({max} workgroups per dimension)"
            )));
        }
        Ok(())
    }

    /// The largest storage buffer the device binds whole: the lesser of its `max_buffer_size` and
    /// `max_storage_buffer_binding_size` (what a growing buffer may double up to).
    pub(crate) fn storage_limit(&self) -> u64 {
        let limits = self.device.limits();
        limits
            .max_buffer_size
            .min(limits.max_storage_buffer_binding_size)
    }

    /// Refuses, with [`Error::Gpu`], a storage buffer of `bytes` larger than the device's
    /// `max_buffer_size` or `max_storage_buffer_binding_size` (buffers are bound whole).
    pub(crate) fn check_storage(&self, what: &str, bytes: u64) -> Result<()> {
        let max = self.storage_limit();
        if bytes.max(256).next_multiple_of(256) > max {
            return Err(Error::Gpu(format!(
                "{what}: a {bytes}-byte storage buffer exceeds this device's limit of {max} bytes"
            )));
        }
        Ok(())
    }

    /// A command encoder to record a frame's GPU work into.
    pub fn encoder(&self) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("kinetrace frame"),
            })
    }

    /// Submits recorded work; it runs asynchronously. The encoder is finished and submitted inside
    /// validation and out-of-memory error scopes: a device error (a dispatch past a limit, a buffer too
    /// large to allocate) is kept and returned as [`Error::Gpu`] by the next [`wait`](Self::wait) or
    /// read-back instead of reaching wgpu's default handler, which panics.
    pub fn submit(&self, encoder: wgpu::CommandEncoder) -> wgpu::SubmissionIndex {
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let index = self.queue.submit([encoder.finish()]);
        self.counters.submissions.fetch_add(1, Relaxed);
        // Native scopes resolve at once; block_on only unwraps the future.
        let errors = [
            pollster::block_on(validation.pop()),
            pollster::block_on(memory.pop()),
        ];
        if let Some(e) = errors.into_iter().flatten().next() {
            let mut failure = self.failure.lock().expect("gpu failure");
            failure.get_or_insert_with(|| e.to_string());
        }
        index
    }

    /// Running totals of the traffic through this device (shared by clones).
    pub fn counters(&self) -> GpuCounters {
        let c = &self.counters;
        GpuCounters {
            uploaded_bytes: c.uploaded.load(Relaxed),
            read_back_bytes: c.read_back.load(Relaxed),
            submissions: c.submissions.load(Relaxed),
            blocking_waits: c.waits.load(Relaxed),
            allocated_bytes: c.allocated.load(Relaxed),
        }
    }

    /// Counts a device buffer of `bytes` created.
    pub(crate) fn count_allocated(&self, bytes: u64) {
        self.counters.allocated.fetch_add(bytes, Relaxed);
    }

    /// Queues a write of `data` into `buffer` at `offset`, counted as uploaded.
    pub(crate) fn write_buffer(&self, buffer: &wgpu::Buffer, offset: u64, data: &[u8]) {
        self.counters.uploaded.fetch_add(data.len() as u64, Relaxed);
        self.queue.write_buffer(buffer, offset, data);
    }

    /// Queues a write into `buffer` at `offset` of several byte slices one after the other, counted as
    /// uploaded: slice `k` is `part(k)`, and starts `starts[k]` bytes in (`starts` ends with the total,
    /// so part `k` is `starts[k + 1] − starts[k]` bytes long). Written straight into the queue's staging
    /// memory, a mebibyte per task across threads where `parallel` (the copy of a large upload is the
    /// CPU's whole share of it: about 2 ms for 12 MB on one core of a 2-core VM).
    pub(crate) fn write_buffer_parts<'a>(
        &self,
        buffer: &wgpu::Buffer,
        offset: u64,
        starts: &[u64],
        part: impl Fn(usize) -> &'a [u8] + Sync,
        parallel: bool,
    ) {
        let total = starts.last().copied().unwrap_or(0);
        let Some(size) = wgpu::BufferSize::new(total) else {
            return;
        };
        self.counters.uploaded.fetch_add(total, Relaxed);
        // A write out of the buffer's bounds is refused here, and reported as `write_buffer`'s would be.
        let Some(mut view) = self.queue.write_buffer_with(buffer, offset, size) else {
            return;
        };
        copy_parts(view.slice(..), starts, &part, parallel);
    }

    /// Counts `bytes` copied to staging for reading back.
    pub(crate) fn count_read_back(&self, bytes: u64) {
        self.counters.read_back.fetch_add(bytes, Relaxed);
    }

    /// The device error of an earlier submission, once: [`Error::Gpu`] when there was one.
    pub(crate) fn take_failure(&self) -> Result<()> {
        match self.failure.lock().expect("gpu failure").take() {
            Some(e) => Err(Error::Gpu(e)),
            None => Ok(()),
        }
    }

    /// Blocks until all submitted work has finished. Surfaces device loss, and a device error of an
    /// earlier submission, as [`Error::Gpu`].
    pub fn wait(&self) -> Result<()> {
        self.counters.waits.fetch_add(1, Relaxed);
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| Error::Gpu(e.to_string()))?;
        self.take_failure()
    }

    /// Polls without blocking, driving pending read-backs forward.
    pub fn poll(&self) {
        let _ = self.device.poll(wgpu::PollType::Poll);
    }
}

/// Traffic between the CPU and a [`GpuContext`]: running totals from [`GpuContext::counters`], or one
/// frame's share of them ([`since`](Self::since)) as in `TraceStats::gpu`. Counting costs an atomic add per
/// upload, read-back, submission and wait.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpuCounters {
    /// Bytes written to GPU buffers from the CPU (vertex data, trees, rays, parameters).
    pub uploaded_bytes: u64,
    /// Bytes copied to staging buffers for reading back.
    pub read_back_bytes: u64,
    /// Command buffers submitted.
    pub submissions: u64,
    /// Times the CPU blocked until the GPU finished (a [`GpuContext::wait`], a `Readback::wait` that found
    /// its results not yet there).
    pub blocking_waits: u64,
    /// Bytes of device buffers created (trees, build scratch, staging), at their allocated sizes: what
    /// the `memory_bytes` of the GPU trees and builders add up, checked against it in
    /// `tests/gpu_memory.rs`. A frame's share is nonzero when it made or grew buffers (a first build, a
    /// mesh that grew, a larger ray batch); buffers dropped are not subtracted.
    pub allocated_bytes: u64,
}

impl GpuCounters {
    /// What happened between `earlier` and these totals.
    pub fn since(&self, earlier: &GpuCounters) -> GpuCounters {
        GpuCounters {
            uploaded_bytes: self.uploaded_bytes - earlier.uploaded_bytes,
            read_back_bytes: self.read_back_bytes - earlier.read_back_bytes,
            submissions: self.submissions - earlier.submissions,
            blocking_waits: self.blocking_waits - earlier.blocking_waits,
            allocated_bytes: self.allocated_bytes - earlier.allocated_bytes,
        }
    }
}

#[derive(Default)]
struct CounterCells {
    uploaded: AtomicU64,
    read_back: AtomicU64,
    submissions: AtomicU64,
    waits: AtomicU64,
    allocated: AtomicU64,
}

/// A Vulkan-only wgpu instance for compute.
///
/// Where Vulkan is the window-system API (Linux and the BSDs), wgpu enables the Xlib, XCB and Wayland
/// surface extensions on every instance. Mesa's implicit device-select layer sees them and, while listing
/// adapters, connects to the Wayland compositor and the X server to find the GPU driving the display; on a
/// headless machine libwayland prints `error: XDG_RUNTIME_DIR is invalid or not set in the environment.`
/// once per listing. A compute device presents nothing, so this instance enables none of those three
/// extensions: no display connection is attempted and nothing is printed. `None` elsewhere, when
/// `WGPU_BACKEND` leaves Vulkan out, or when no Vulkan instance can be made; the caller then uses wgpu's
/// ordinary instance, which also tries the other back ends.
fn headless_vulkan(desc: &wgpu::InstanceDescriptor) -> Option<wgpu::Instance> {
    #[cfg(all(
        unix,
        not(target_os = "macos"),
        not(target_os = "ios"),
        not(target_os = "android")
    ))]
    if desc.backends.contains(wgpu::Backends::VULKAN) {
        let hal_desc = wgpu::hal::InstanceDescriptor {
            name: "kinetrace",
            flags: desc.flags,
            memory_budget_thresholds: desc.memory_budget_thresholds,
            backend_options: desc.backend_options.clone(),
            telemetry: None,
            display: None,
        };
        let headless: Box<wgpu::hal::vulkan::CreateInstanceCallback> = Box::new(|args| {
            args.extensions.retain(|e| {
                ![
                    c"VK_KHR_xlib_surface",
                    c"VK_KHR_xcb_surface",
                    c"VK_KHR_wayland_surface",
                ]
                .contains(e)
            })
        });
        // SAFETY: the descriptor is wgpu's own, from the environment. The callback only drops window-system
        // surface extensions, which wgpu-hal reads in one place: creating a surface of that kind, where it
        // checks for the extension and returns an error without it. This instance never creates a surface.
        // `from_hal` takes ownership of a valid Vulkan instance.
        match unsafe { wgpu::hal::vulkan::Instance::init_with_callback(&hal_desc, Some(headless)) }
        {
            Ok(hal) => {
                return Some(unsafe { wgpu::Instance::from_hal::<wgpu::hal::api::Vulkan>(hal) });
            }
            // No Vulkan loader: wgpu's ordinary instance reports that, and tries other back ends.
            Err(e) => log::debug!("kinetrace: headless Vulkan instance: {e}"),
        }
    }
    let _ = desc; // unused where Vulkan is not the window-system API
    None
}

/// Test hook (feature `testing`): the shared context of the integration tests, created once per process,
/// `None` (with the reason printed once) where no adapter exists. With `KINETRACE_REQUIRE_GPU=1` set, a
/// missing adapter panics instead, so that CI cannot pass by skipping.
#[cfg(feature = "testing")]
pub fn shared_for_tests() -> Option<GpuContext> {
    use std::sync::OnceLock;
    static CTX: OnceLock<Option<GpuContext>> = OnceLock::new();
    CTX.get_or_init(|| match GpuContext::new() {
        Ok(c) => {
            eprintln!("kinetrace: GPU tests run on {} ({})", c.adapter_name(), c.adapter_details());
            Some(c)
        }
        Err(e) => {
            if std::env::var("KINETRACE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("KINETRACE_REQUIRE_GPU=1 but no GPU: {e}");
            }
            eprintln!("\n*** kinetrace: SKIPPING GPU TESTS: {e} ***\n*** (install mesa-vulkan-drivers for lavapipe, or set KINETRACE_REQUIRE_GPU=1 to fail) ***\n");
            None
        }
    })
    .clone()
}

/// Bytes a worker copies at a time in [`GpuContext::write_buffer_parts`], and chunks handed out at once.
const COPY_CHUNK: usize = 1 << 20;
const COPY_BATCH: usize = 16;

/// Copies the parts [`GpuContext::write_buffer_parts`] concatenates into `dst`: its whole mebibytes
/// [`COPY_BATCH`] at a time across threads (where `parallel`), the rest here.
fn copy_parts<'a>(
    dst: wgpu::WriteOnly<'_, [u8]>,
    starts: &[u64],
    part: &(impl Fn(usize) -> &'a [u8] + Sync),
    parallel: bool,
) {
    // A fixed-size chunk can go to another thread; a slice's `WriteOnly` cannot (no `Send`).
    let (chunks, rest) = dst.into_chunks::<COPY_CHUNK>();
    let whole = (chunks.len() * COPY_CHUNK) as u64;
    let mut chunks = chunks.into_iter().enumerate();
    loop {
        let mut batch: [_; COPY_BATCH] = std::array::from_fn(|_| chunks.next());
        if batch[0].is_none() {
            break;
        }
        crate::parallel::for_each_mut(parallel, &mut batch, |_, chunk| {
            if let Some((k, chunk)) = chunk.take() {
                copy_range(chunk.into(), (k * COPY_CHUNK) as u64, starts, part);
            }
        });
    }
    copy_range(rest, whole, starts, part);
}

/// Copies into `dst`, which starts `at` bytes into the concatenated parts, its share of them, part by
/// part.
fn copy_range<'a>(
    dst: wgpu::WriteOnly<'_, [u8]>,
    at: u64,
    starts: &[u64],
    part: &(impl Fn(usize) -> &'a [u8] + Sync),
) {
    let end = at + dst.len() as u64;
    let (mut dst, mut pos) = (dst, at);
    // The part holding byte `at`: the last that starts at or before it.
    let mut k = starts.partition_point(|&s| s <= at).saturating_sub(1);
    while pos < end && k + 1 < starts.len() {
        let from = (pos - starts[k]) as usize;
        let to = ((starts[k + 1].min(end) - starts[k]) as usize).max(from);
        let (mut head, rest) = dst.split_at(to - from);
        head.copy_from_slice(&part(k)[from..to]);
        (dst, pos, k) = (rest, pos + (to - from) as u64, k + 1);
    }
}
