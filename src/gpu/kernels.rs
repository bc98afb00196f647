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
        device: &wgpu::Device,
        name: &'static str,
        source: &'static str,
        bindings: &[B],
        entries: &[&'static str],
    ) -> Self {
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
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(name),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
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
    /// DACRT on the task pool.
    pub dacrt: Module,
    /// The BVH build on the task pool.
    pub pool_build: Module,
}

impl Kernels {
    pub fn new(device: &wgpu::Device) -> Self {
        use B::*;
        Self {
            scan: Module::new(
                device,
                "scan",
                shader!("scan.wgsl"),
                &[Write, Write, Uniform],
                &["scan_blocks", "add_offsets"],
            ),
            sort: Module::new(
                device,
                "sort",
                shader!("sort.wgsl"),
                &[Read, Read, Write, Write, Write, Uniform, Uniform],
                &["count", "scatter"],
            ),
            lbvh: Module::new(
                device,
                "lbvh",
                shader!("lbvh.wgsl"),
                &[
                    Read, Read, Write, Write, Write, Write, Write, Write, Write, Uniform,
                ],
                &["tri_bounds", "reduce_bounds", "morton", "karras", "walk_up"],
            ),
            levels: Module::new(
                device,
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
                device,
                "reduce",
                shader!("reduce.wgsl"),
                &[Read, Write, Uniform],
                &["sum_blocks", "sum_pairs"],
            ),
            trace: Module::new(
                device,
                "trace",
                shader!(rays "trace.wgsl"),
                &[Read, Read, Read, Read, Read, Write, Uniform],
                &["closest", "any_hit"],
            ),
            scene: Module::new(
                device,
                "scene",
                shader!(rays "scene.wgsl"),
                &[
                    Read, Read, Read, Read, Read, Read, Read, Read, Write, Uniform,
                ],
                &["scene_trace"],
            ),
            skin: Module::new(
                device,
                "skin",
                shader!("skin.wgsl"),
                &[Read, Read, Read, Read, Write, Uniform, Read, Read],
                &["skin"],
            ),
            frame: Module::new(
                device,
                "frame",
                shader!("frame.wgsl"),
                &[Read, Read, Read, Read, Write, Write, Uniform],
                &["instance_boxes", "order_instances"],
            ),
            frame_sah: Module::new(
                device,
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
                device,
                "histogram",
                shader!("histogram.wgsl"),
                &[Read, Write, Uniform],
                &["histogram_clear", "histogram"],
            ),
            collide: Module::new(
                device,
                "collide",
                shader!("collide.wgsl"),
                &[
                    Read, Read, Read, Write, Write, Write, Write, Uniform, Uniform,
                ],
                &["pairs_init", "pairs_args", "pairs_round"],
            ),
            sah: Module::new(
                device,
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
                device,
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
                device,
                "raysort",
                shader!("raysort_keys.wgsl"),
                &[Read, Write, Write, Write, Write, Uniform],
                &["origin_bounds", "ray_keys", "gather_invalid", "gather_keys"],
            ),
            raysort_crsh: Module::new(
                device,
                "raysort_crsh",
                shader!(rays "raysort_crsh.wgsl"),
                &[Read, Read, Read, Read, Read, Write],
                &["crsh_trace"],
            ),
            dacrt: Module::new(
                device,
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
                device,
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
                device,
                "taskpool",
                concat!(
                    shader!("taskpool.wgsl"),
                    include_str!("../../shaders/taskpool_sum.wgsl")
                ),
                &[Read, Write, Write, Write, Write, Uniform, Write],
                POOL_ENTRIES,
            ),
        }
    }
}
