//! What the planner chooses among when a tree is rebuilt: a builder on a device, and what is assumed of a
//! build before it was measured.

use crate::bvh::Builder;
use std::fmt;

/// Where a tree is built.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Device {
    /// On the CPU (all threads with the `parallel` feature).
    #[default]
    Cpu,
    /// On the GPU (feature `gpu`), which builds LBVH over 30-bit codes ([`Build::GPU_LBVH`]), 16-bin SAH
    /// ([`Build::GPU_SAH`]), their hybrid ([`Build::gpu_hybrid`]), PLOC (`Builder::Ploc` of any radius,
    /// [`Build::GPU_PLOC`]) and the spatial median on the task pool ([`Build::GPU_MEDIAN`]); the tree is
    /// read back so that CPU queries can use it.
    Gpu,
}

/// A way to rebuild a tree: a builder on a device.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Build {
    /// The algorithm ([`Builder::Hybrid`] takes its number of LBVH levels `k`).
    pub builder: Builder,
    /// Where it runs.
    pub device: Device,
}

impl Build {
    /// `builder` on the CPU.
    pub const fn cpu(builder: Builder) -> Build {
        Build {
            builder,
            device: Device::Cpu,
        }
    }

    /// LBVH over 30-bit codes on the GPU: the fastest GPU build.
    pub const GPU_LBVH: Build = Build {
        builder: Builder::LBVH,
        device: Device::Gpu,
    };

    /// 16-bin SAH on the GPU with work queues (`gpu::GpuSahBuilder`): CPU binned-SAH quality (within
    /// about 10%), a GPU build's time.
    pub const GPU_SAH: Build = Build {
        builder: Builder::SAH,
        device: Device::Gpu,
    };

    /// The GPU hybrid: `k` LBVH levels, 16-bin SAH below (fewer LBVH levels on clustered meshes).
    pub const fn gpu_hybrid(k: u32) -> Build {
        Build {
            builder: Builder::hybrid(k),
            device: Device::Gpu,
        }
    }

    /// PLOC with the paper's radius 16 on the GPU: the same tree as the CPU's PLOC, node for node.
    pub const GPU_PLOC: Build = Build {
        builder: Builder::PLOC,
        device: Device::Gpu,
    };

    /// The spatial median on the GPU task pool (`gpu::taskpool::build_bvh`): the CPU median builder's tree
    /// with one triangle per leaf (node for node where no range of more than 32 triangles needs its
    /// fallback cut), and a few pool rounds per level of the tree.
    pub const GPU_MEDIAN: Build = Build {
        builder: Builder::Median,
        device: Device::Gpu,
    };

    /// The prior of the planner, before this build was measured on a mesh: the SAH cost of its trees over
    /// a binned-SAH tree's on the same triangles. LBVH's Morton codes waste levels on clustered triangles
    /// (the characteriser's non-uniform profile), so its prior is worse there. Our numbers, read off the
    /// report's fresh-build ratios (docs/BENCHMARKS.md); measurements replace them at once.
    pub fn prior_quality(&self, clustered: bool) -> f64 {
        match self.builder {
            Builder::Sah { .. } => 1.0,
            Builder::Hybrid { .. } => 1.05,
            Builder::Lbvh { .. } if clustered => 1.35,
            Builder::Lbvh { .. } => 1.15,
            Builder::Median => 1.3,
            // Meister and Bittner report PLOC at r = 16 within a few per cent of a full SAH sweep.
            Builder::Ploc { .. } => 1.05,
        }
    }

    /// The prior of the planner for this build's time relative to another's before it was measured: CPU
    /// LBVH 1, median 2, hybrid and PLOC 2.5, binned SAH 5; a GPU build the same as its CPU twin (no device is
    /// assumed faster: the exploration's optimism, one spread, is what gets a GPU tried).
    pub fn prior_time(&self) -> f64 {
        match self.builder {
            Builder::Lbvh { .. } => 1.0,
            Builder::Median => 2.0,
            Builder::Hybrid { .. } => 2.5,
            Builder::Sah { .. } => 5.0,
            Builder::Ploc { .. } => 2.5,
        }
    }
}

impl From<Builder> for Build {
    fn from(builder: Builder) -> Build {
        Build::cpu(builder)
    }
}

impl fmt::Display for Build {
    /// The builder's name, with `-gpu` for GPU builds (`lbvh`, `lbvh-gpu`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let device = match self.device {
            Device::Cpu => "",
            Device::Gpu => "-gpu",
        };
        write!(f, "{}{device}", self.builder.name())
    }
}
