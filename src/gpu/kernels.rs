//! Every WGSL kernel of the crate, compiled once per device, with explicit bind group layouts (one per
//! shader file, shared by its entry points; the uniform parameters use dynamic offsets so one buffer holds
//! the parameters of many dispatches).

use std::collections::HashMap;

/// How a binding is used by a shader file.
#[derive(Clone, Copy)]
enum B {
    /// `var<storage, read>`
    Read,
    /// `var<storage, read_write>`
    Write,
    /// `var<uniform>` with a dynamic offset
    Uniform,
}

/// One shader file: its layout and a pipeline per entry point.
pub(crate) struct Module {
    pub layout: wgpu::BindGroupLayout,
    pipelines: HashMap<&'static str, wgpu::ComputePipeline>,
}

impl Module {
    fn new(
        compiler: &Compiler,
        name: &'static str,
        source: &'static str,
        bindings: &[B],
        entries: &[&'static str],
    ) -> Self {
        let device = compiler.device;
        let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: match b {
                        B::Read => wgpu::BufferBindingType::Storage { read_only: true },
                        B::Write => wgpu::BufferBindingType::Storage { read_only: false },
                        B::Uniform => wgpu::BufferBindingType::Uniform,
                    },
                    has_dynamic_offset: matches!(b, B::Uniform),
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(name),
            entries: &layout_entries,
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(name),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let (shader, precise) = super::precise::shader_module(device, name, source);
        compiler.precise.set(compiler.precise.get() && precise);
        let pipelines = entries
            .iter()
            .map(|&e| {
                let p = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(e),
                    layout: Some(&pipeline_layout),
                    module: &shader,
                    entry_point: Some(e),
                    compilation_options: Default::default(),
                    cache: None,
                });
                (e, p)
            })
            .collect();
        Self { layout, pipelines }
    }

    /// The pipeline of an entry point.
    pub fn pipeline(&self, entry: &str) -> &wgpu::ComputePipeline {
        &self.pipelines[entry]
    }
}

/// A kernel file with common.wgsl (and, for `rays`, the ray tests) prepended: WGSL has no includes.
macro_rules! shader {
    ($file:literal) => {
        concat!(
            include_str!("../../shaders/common.wgsl"),
            include_str!(concat!("../../shaders/", $file))
        )
    };
    (rays $file:literal) => {
        concat!(
            include_str!("../../shaders/common.wgsl"),
            include_str!("../../shaders/ray_tests.wgsl"),
            include_str!(concat!("../../shaders/", $file))
        )
    };
}

/// The entry points of every task-pool module (shaders/taskpool.wgsl's core).
const POOL_ENTRIES: &[&str] = &[
    "pool_plan",
    "pool_size",
    "pool_work",
    "pool_advance",
    "pool_finish",
];

/// All kernels of the crate.
pub(crate) struct Kernels {
    pub scan: Module,
    pub sort: Module,
    pub lbvh: Module,
    pub levels: Module,
    pub reduce: Module,
    pub trace: Module,
    pub scene: Module,
    pub skin: Module,
    pub shadow_map: Module,
    /// The hard selective shadow classification against the map `shadow_map` renders.
    pub shadow_classify: Module,
    pub frame: Module,
    /// The resident frame's SAH cost reduction (reduce.wgsl with `sah_blocks` appended).
    pub frame_sah: Module,
    pub histogram: Module,
    pub collide: Module,
    pub sah: Module,
    pub ploc: Module,
    pub raysort: Module,
    pub raysort_crsh: Module,
    /// The task pool's toy task (a test hook).
    #[cfg(feature = "testing")]
    pub taskpool: Module,
    /// Correctly rounded division and square root (a test hook).
    #[cfg(feature = "testing")]
    pub divide: Module,
    /// DACRT on the task pool.
    pub dacrt: Module,
    /// The BVH build on the task pool.
    pub pool_build: Module,
    /// Every kernel was compiled without floating-point contraction (see `precise`).
    pub contraction_free: bool,
}

/// The device the kernels are compiled for, and whether every one of them so far was compiled without
/// floating-point contraction.
struct Compiler<'a> {
    device: &'a wgpu::Device,
    precise: std::cell::Cell<bool>,
}

impl Kernels {
    pub fn new(device: &wgpu::Device) -> Self {
        use B::*;
        let compiler = Compiler {
            device,
            precise: std::cell::Cell::new(true),
        };
        let kernels = Self {
            scan: Module::new(
                &compiler,
                "scan",
                shader!("scan.wgsl"),
                &[Write, Write, Uniform],
                &["scan_blocks", "add_offsets"],
            ),
            sort: Module::new(
                &compiler,
                "sort",
                shader!("sort.wgsl"),
                &[Read, Read, Write, Write, Write, Uniform, Uniform],
                &["count", "scatter"],
            ),
            lbvh: Module::new(
                &compiler,
                "lbvh",
                shader!("lbvh.wgsl"),
                &[
                    Read, Read, Write, Write, Write, Write, Write, Write, Write, Uniform,
                ],
                &["tri_bounds", "reduce_bounds", "morton", "karras", "walk_up"],
            ),
            levels: Module::new(
                &compiler,
                "levels",
                shader!("levels.wgsl"),
                &[Read, Read, Read, Write, Write, Write, Write, Uniform, Write],
                &[
                    "level_reset",
                    "level_count",
                    "level_offsets",
                    "level_scatter",
                    "leaf_bounds",
                    "bounds_level",
                ],
            ),
            reduce: Module::new(
                &compiler,
                "reduce",
                shader!("reduce.wgsl"),
                &[Read, Write, Uniform],
                &["sum_blocks", "sum_pairs"],
            ),
            trace: Module::new(
                &compiler,
                "trace",
                shader!(rays "trace.wgsl"),
                &[Read, Read, Read, Read, Read, Write, Uniform],
                &["closest", "any_hit"],
            ),
            scene: Module::new(
                &compiler,
                "scene",
                shader!(rays "scene.wgsl"),
                &[
                    Read, Read, Read, Read, Read, Read, Read, Read, Write, Uniform,
                ],
                &["scene_trace"],
            ),
            skin: Module::new(
                &compiler,
                "skin",
                shader!("skin.wgsl"),
                &[Read, Read, Read, Read, Write, Uniform, Read, Read],
                &["skin"],
            ),
            shadow_map: Module::new(
                &compiler,
                "shadow_map",
                shader!("shadow_map.wgsl"),
                &[Read, Read, Read, Write, Write, Write, Write, Read],
                &["map_top", "map_small", "map_plan", "map_large"],
            ),
            shadow_classify: Module::new(
                &compiler,
                "shadow_classify",
                shader!("shadow_classify.wgsl"),
                &[Read, Read, Read, Write, Write, Read],
                &["classify_hard"],
            ),
            frame: Module::new(
                &compiler,
                "frame",
                shader!("frame.wgsl"),
                &[Read, Read, Read, Read, Write, Write, Uniform],
                &["instance_boxes", "order_instances"],
            ),
            frame_sah: Module::new(
                &compiler,
                "frame_sah",
                concat!(
                    include_str!("../../shaders/common.wgsl"),
                    include_str!("../../shaders/reduce.wgsl"),
                    include_str!("../../shaders/frame_sah.wgsl")
                ),
                &[Read, Write, Uniform, Read],
                &["sah_blocks", "sum_pairs"],
            ),
            histogram: Module::new(
                &compiler,
                "histogram",
                shader!("histogram.wgsl"),
                &[Read, Write, Uniform],
                &["histogram_clear", "histogram"],
            ),
            collide: Module::new(
                &compiler,
                "collide",
                shader!("collide.wgsl"),
                &[
                    Read, Read, Read, Write, Write, Write, Write, Uniform, Uniform,
                ],
                &["pairs_init", "pairs_args", "pairs_round"],
            ),
            sah: Module::new(
                &compiler,
                "sah",
                shader!("sah_build.wgsl"),
                &[
                    Read, Read, Write, Write, Write, Write, Write, Write, Write, Write, Read,
                    Uniform,
                ],
                &[
                    "sah_frame",
                    "sah_prims",
                    "sah_args",
                    "sah_small_args",
                    "sah_bounds",
                    "sah_bin",
                    "sah_split",
                    "sah_flag",
                    "sah_scatter",
                    "sah_copy",
                    "sah_small",
                ],
            ),
            ploc: Module::new(
                &compiler,
                "ploc",
                shader!("ploc.wgsl"),
                &[
                    Read, Read, Read, Write, Write, Write, Write, Write, Write, Write, Write,
                    Uniform, Write,
                ],
                &[
                    "ploc_init",
                    "ploc_nearest",
                    "ploc_merge",
                    "ploc_block_scan",
                    "ploc_compact",
                    "ploc_advance",
                ],
            ),
            raysort: Module::new(
                &compiler,
                "raysort",
                shader!("raysort_keys.wgsl"),
                &[Read, Write, Write, Write, Write, Uniform],
                &["origin_bounds", "ray_keys", "gather_invalid", "gather_keys"],
            ),
            raysort_crsh: Module::new(
                &compiler,
                "raysort_crsh",
                shader!(rays "raysort_crsh.wgsl"),
                &[Read, Read, Read, Read, Read, Write],
                &["crsh_trace"],
            ),
            dacrt: Module::new(
                &compiler,
                "dacrt",
                concat!(
                    shader!(rays "taskpool.wgsl"),
                    include_str!("../../shaders/taskpool_dacrt.wgsl")
                ),
                &[
                    Read, Write, Write, Write, Write, Uniform, Write, Read, Write, Write, Write,
                ],
                POOL_ENTRIES,
            ),
            pool_build: Module::new(
                &compiler,
                "pool_build",
                concat!(
                    shader!("taskpool.wgsl"),
                    include_str!("../../shaders/taskpool_build.wgsl")
                ),
                &[
                    Read, Write, Write, Write, Write, Uniform, Write, Read, Write, Write, Write,
                ],
                POOL_ENTRIES,
            ),
            #[cfg(feature = "testing")]
            taskpool: Module::new(
                &compiler,
                "taskpool",
                concat!(
                    shader!("taskpool.wgsl"),
                    include_str!("../../shaders/taskpool_sum.wgsl")
                ),
                &[Read, Write, Write, Write, Write, Uniform, Write],
                POOL_ENTRIES,
            ),
            #[cfg(feature = "testing")]
            divide: Module::new(
                &compiler,
                "divide",
                shader!("divide.wgsl"),
                &[Read, Read, Write],
                &["divide", "root"],
            ),
            contraction_free: false,
        };
        Self {
            contraction_free: compiler.precise.get(),
            ..kernels
        }
    }
}
