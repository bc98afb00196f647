//! One mesh of the GPU-resident frame: its tree, its skin, and the refit-or-rebuild rule fed by the
//! degradation metric (and, measured, the SAH cost) read back one frame late, and a CPU-side box of its
//! vertices.

use super::bound::{self, SkinBound};
use super::sah::{SahReadback, SahReading, SahReduction};
use crate::anim::{MorphTargets, SkinWeights};
use crate::bvh::Builder;
use crate::gpu::{
    DegradationReadback, GpuContext, GpuMeshBvh, GpuSahBuilder, GpuSahOptions, GpuSkin,
};
use crate::{Aabb, Mesh, Result};
use glam::{Mat4, Vec3};

/// What changed about a resident mesh this frame.
#[derive(Clone, Copy, Debug)]
pub enum MeshUpdate<'a> {
    /// Nothing: its tree stays as it is (rigid and static meshes, a skin whose matrices did not change).
    Unchanged,
    /// New joint matrices for its [`GpuSkin`] (uploads 64 bytes per joint) and, for a skin made with
    /// blend shapes, their weights (4 bytes per target; empty without).
    Joints {
        /// The palette.
        matrices: &'a [Mat4],
        /// One weight per blend shape of the skin.
        morph_weights: &'a [f32],
    },
    /// New vertex positions from the CPU (uploads 12 bytes per vertex): meshes deformed by gameplay code
    /// or by blend shapes, which the GPU skin does not apply.
    Positions(&'a [Vec3]),
}

/// What [`ResidentMesh::record`] recorded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Maintained {
    /// Nothing changed.
    Kept,
    /// Refitted, with the degradation metric on its way back.
    Refit,
    /// Rebuilt with this builder: the first build, or the rule asked for it.
    Rebuilt(FrameBuilder),
}

/// A GPU builder that rebuilds a resident tree inside the frame's one submission, writing into the
/// mesh's own buffers. PLOC (a read-back per round), the task pool's median build (a tree for the CPU)
/// and builds over other bin counts or 63-bit codes are not among them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameBuilder {
    /// LBVH over 30-bit codes ([`GpuMeshBvh::record_build`]): the cheapest build, no scratch beyond the
    /// tree's own.
    Lbvh,
    /// 16-bin SAH or the hybrid ([`GpuSahBuilder`] with these options): better trees, about five (SAH)
    /// or two and a half (hybrid) times LBVH's work, and a few KiB of scratch per options used (nothing
    /// per triangle from about 500 triangles on: the scratch lives in the tree's buffers), made at the
    /// mesh's first build with them and kept.
    Sah(GpuSahOptions),
}

impl FrameBuilder {
    /// How the frame runs `builder` (a hybrid on a `clustered` mesh with fewer LBVH levels,
    /// [`hybrid_levels`](crate::gpu::hybrid_levels)); `None` where it cannot in one submission.
    pub fn of(builder: Builder, clustered: bool) -> Option<FrameBuilder> {
        GpuSahOptions::for_builder(builder, clustered).map(|o| o.map_or(Self::Lbvh, Self::Sah))
    }
}

/// What a resident mesh knows of its tree when it decides whether to rebuild: the metric of an earlier
/// refit, read back without blocking (one frame late, or more when the GPU is behind).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefitState<'a> {
    /// The most recent degradation metric read back (0 after a rebuild, before its first refit's).
    pub degradation: f32,
    /// Refits recorded since the tree was last built.
    pub frames_since_rebuild: u32,
    /// With [`ResidentMesh::measure_costs`], the SAH cost read back since the last call (of a refitted
    /// tree, or of a rebuilt one: [`CostReading::rebuilt`]); each reading is given once.
    pub cost: Option<CostReading>,
    /// Whether the tree was never built: the rule must name a builder (`None` then builds with LBVH).
    pub first_build: bool,
    /// With a rebuilt tree's [`cost`](Self::cost), the costs of the trees built before it on the same
    /// pose only to be measured (see [`ResidentMesh::record`]), in the order they were asked for.
    pub calibrated: &'a [Calibrated],
}

/// The SAH cost of a tree built only to be measured, on the pose of the rebuild that followed it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Calibrated {
    /// The builder measured.
    pub builder: FrameBuilder,
    /// Its tree's cost and root area.
    pub reading: SahReading,
}

/// A tree's SAH cost as read back for [`RefitState::cost`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostReading {
    /// The cost and root area.
    pub reading: SahReading,
    /// Whether it is the cost of a fresh build (else of a refit).
    pub rebuilt: bool,
}

impl RefitState<'_> {
    /// Mean rise of the degradation per refit since the last build.
    pub fn incoherence(&self) -> f32 {
        self.degradation / self.frames_since_rebuild.max(1) as f32
    }
}

/// A mesh kept on the GPU for the resident frame: uploaded once ([`new`](Self::new): positions, indices,
/// and for a skinned mesh its rest pose and weights), then per frame only what [`MeshUpdate`] names.
///
/// The refit-or-rebuild rule is the caller's, on the metric of an earlier refit ([`RefitState`]): the
/// metric of frame n's refit comes back without blocking and decides frame n+1 (or later, if the GPU is
/// behind): a rebuild one frame late. Each rebuild uses the [`FrameBuilder`] the rule names.
pub struct ResidentMesh {
    bvh: GpuMeshBvh,
    skin: Option<GpuSkin>,
    /// The SAH and hybrid builders used so far, one per options (their scratch is bound to `bvh`).
    sah: Vec<GpuSahBuilder>,
    built: bool,
    /// The last refit's metric, not yet read back.
    pending: Option<DegradationReadback>,
    /// The most recent metric read back (0 after a rebuild).
    degradation: f32,
    /// Refits since the last build.
    refits: u32,
    /// The SAH cost reduction, with [`measure_costs`](Self::measure_costs).
    costs: Option<SahReduction>,
    /// The last cost recorded, not yet read back, and whether it is a rebuild's.
    pending_cost: Option<(SahReadback, bool)>,
    /// A cost read back and not yet given to the rule.
    unread: Option<CostReading>,
    /// The trees built only to be measured before the rebuild whose cost is `pending_cost`.
    pending_calibrations: Vec<(FrameBuilder, SahReadback)>,
    /// Their costs read back with `unread`.
    calibrated: Vec<Calibrated>,
    /// The builders the rule asks to measure this frame (kept to reuse its allocation).
    calibrate: Vec<FrameBuilder>,
    /// The skin's bound from joint matrices (`None` without a skin or for weights it cannot bound).
    skin_bound: Option<SkinBound>,
    /// A box of this frame's vertices ([`bound`](Self::bound)).
    bound: Aabb,
}

impl ResidentMesh {
    /// Uploads `mesh` (and, with `skin`, its rest pose, weights, a palette of `joints` matrices and any
    /// blend shapes) and allocates its tree; nothing is built until the first [`record`](Self::record).
    /// Costs the uploads (12 bytes per vertex and 12 per triangle, 36 more per vertex for a skin, 12 per
    /// vertex per blend shape) and about 112 bytes of GPU memory per triangle, plus a SAH or hybrid
    /// builder's scratch once one is used ([`FrameBuilder::Sah`]).
    pub fn new(
        ctx: &GpuContext,
        mesh: &Mesh,
        skin: Option<(&SkinWeights, usize, Option<&MorphTargets>)>,
    ) -> Result<Self> {
        let bvh = GpuMeshBvh::new(ctx, mesh)?;
        let (skin, skin_bound) = match skin {
            Some((weights, joints, morphs)) => {
                let rest = mesh.positions();
                (
                    Some(GpuSkin::new_morphed(
                        ctx, rest, weights, joints, morphs, &bvh,
                    )?),
                    SkinBound::new(rest, weights, joints, morphs),
                )
            }
            None => (None, None),
        };
        Ok(Self {
            bvh,
            skin,
            sah: Vec::new(),
            built: false,
            pending: None,
            degradation: 0.0,
            refits: 0,
            costs: None,
            pending_cost: None,
            unread: None,
            pending_calibrations: Vec::new(),
            calibrated: Vec::new(),
            calibrate: Vec::new(),
            skin_bound,
            bound: bound::of_points(mesh.positions()),
        })
    }

    /// Reduces the tree's SAH cost on the GPU after every rebuild and refit from now on, read back
    /// without blocking into [`RefitState::cost`] (one reading in flight at a time: a refit recorded while
    /// one is on its way is not measured). Costs two dispatches over the nodes and 40 bytes read back per
    /// measured update, 8 bytes of GPU memory per 256 nodes. The adaptive policy's input.
    pub fn measure_costs(&mut self, ctx: &GpuContext) {
        if self.costs.is_none() {
            self.costs = Some(SahReduction::new(ctx, &self.bvh));
        }
    }

    /// A box of the vertices as of the last [`record`](Self::record), known on the CPU without a
    /// read-back (see `bound`): from the joint matrices for a GPU skin (empty where the skin's weights
    /// cannot be bounded: negative or non-finite), from the positions otherwise. Object space.
    pub fn bound(&self) -> Option<Aabb> {
        (self.skin.is_none() || self.skin_bound.is_some()).then_some(self.bound)
    }

    /// Whether the GPU skins this mesh.
    pub fn skinned(&self) -> bool {
        self.skin.is_some()
    }

    /// The tree, for the frame's scene.
    pub fn bvh(&self) -> &GpuMeshBvh {
        &self.bvh
    }

    /// GPU bytes of the tree and what builds it: the mesh, the nodes, the LBVH's buffers and the scratch of
    /// every SAH or hybrid builder used so far — the thesis's count (§5.4.1; target 113 bytes per triangle,
    /// met from a character's size on: 111.8 at 9,922 triangles with LBVH, SAH and the hybrid used, 112.0
    /// with the device's [`GpuContext::shared_tree_bytes`] added; no parameter slot per tree level). A
    /// skin's rest pose and weights and the cost reduction's block sums are not included.
    pub fn tree_bytes(&self) -> u64 {
        self.bvh.memory_bytes()
            + self
                .sah
                .iter()
                .map(GpuSahBuilder::memory_bytes)
                .sum::<u64>()
    }

    /// Whether the tree was built (by a first [`record`](Self::record)).
    pub fn built(&self) -> bool {
        self.built
    }

    /// The most recent degradation metric read back (0 after a rebuild, before the first refit's).
    pub fn degradation(&self) -> f32 {
        self.degradation
    }

    /// Records this frame's update and maintenance into `encoder`: skinning or the position upload, then
    /// a refit (and its metric's read-back) or, where `rebuild` names a builder for the state read back so
    /// far, a rebuild with it. `rebuild` is called for a changed mesh and for one never built
    /// ([`RefitState::first_build`]: a tree is built whatever it says). Never blocks; a SAH or hybrid
    /// builder used for the first time allocates its scratch. Errors: those of the skin, the upload and
    /// the builder's allocation ([`Error::Gpu`](crate::Error::Gpu) past the device's limits).
    ///
    /// With a rebuild, and costs [measured](Self::measure_costs), the builders `rebuild` pushes onto its
    /// second argument (empty when called) are built first, in order, on the same pose, each tree's cost
    /// reduced and read back before the next build overwrites it: builds measured without being put in
    /// use (the adaptive policy's calibration), given back in [`RefitState::calibrated`] with the
    /// rebuild's own cost (none where a later rebuild replaced that reading on its way). Each costs its
    /// build and a cost reading; nothing is allocated once the list has held as many.
    pub fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        update: MeshUpdate<'_>,
        rebuild: impl FnOnce(&RefitState, &mut Vec<FrameBuilder>) -> Option<FrameBuilder>,
    ) -> Result<Maintained> {
        if let Some(r) = &self.pending
            && let Some(metric) = r.try_take(ctx)
        {
            self.degradation = metric?;
            self.pending = None;
        }
        // The calibrations were recorded before the rebuild's reading: taken with it, all at once.
        if let Some((r, rebuilt)) = &self.pending_cost
            && self.pending_calibrations.iter().all(|c| c.1.ready(ctx))
            && let Some(reading) = r.try_take(ctx)
        {
            self.unread = Some(CostReading {
                reading: reading?,
                rebuilt: *rebuilt,
            });
            self.pending_cost = None;
            for (builder, r) in self.pending_calibrations.drain(..) {
                if let Some(reading) = r.try_take(ctx) {
                    let reading = reading?;
                    self.calibrated.push(Calibrated { builder, reading });
                }
            }
        }
        match (update, &self.skin) {
            (MeshUpdate::Unchanged, _) if self.built => return Ok(Maintained::Kept),
            (MeshUpdate::Unchanged, _) => {}
            (
                MeshUpdate::Joints {
                    matrices,
                    morph_weights,
                },
                Some(skin),
            ) => {
                skin.set_morph_weights(ctx, morph_weights);
                skin.record(ctx, encoder, matrices)?;
                if let Some(b) = &self.skin_bound {
                    self.bound = b.bound(matrices, morph_weights);
                }
            }
            (MeshUpdate::Joints { .. }, None) => {
                return Err(crate::Error::InvalidOption(
                    "joint matrices for a mesh without a GPU skin".into(),
                ));
            }
            (MeshUpdate::Positions(p), _) => {
                self.bvh.upload_positions(ctx, p)?;
                self.bound = bound::of_points(p);
            }
        }
        let state = RefitState {
            degradation: self.degradation,
            frames_since_rebuild: self.refits,
            cost: self.unread.take(),
            first_build: !self.built,
            calibrated: &self.calibrated,
        };
        self.calibrate.clear();
        let chosen = match rebuild(&state, &mut self.calibrate) {
            None if self.built => None,
            chosen => Some(chosen.unwrap_or(FrameBuilder::Lbvh)),
        };
        self.calibrated.clear();
        if let Some(builder) = chosen {
            // Readings of the trees before this rebuild say nothing of this pose.
            self.pending_calibrations.clear();
            if self.costs.is_some() {
                let calibrate = std::mem::take(&mut self.calibrate);
                for &measured in &calibrate {
                    self.record_build(ctx, encoder, measured)?;
                    let costs = self.costs.as_ref().expect("checked above");
                    let r = costs.record(ctx, encoder, &self.bvh);
                    self.pending_calibrations.push((measured, r));
                }
                self.calibrate = calibrate;
            }
            self.record_build(ctx, encoder, builder)?;
            self.built = true;
            self.degradation = 0.0;
            self.refits = 0;
            // A metric of the tree before the rebuild says nothing about the new one.
            self.pending = None;
            self.record_cost(ctx, encoder, true);
            return Ok(Maintained::Rebuilt(builder));
        }
        self.bvh.record_refit(ctx, encoder)?;
        self.refits += 1;
        if self.pending.is_none() {
            self.pending = Some(self.bvh.record_degradation(ctx, encoder));
        }
        self.record_cost(ctx, encoder, false);
        Ok(Maintained::Refit)
    }

    /// Records a full build with `builder`, making its SAH or hybrid scratch first where the mesh has
    /// none of these options yet (kept for later builds: switching between builders allocates and uploads
    /// nothing after each one's first use).
    fn record_build(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        builder: FrameBuilder,
    ) -> Result<()> {
        match builder {
            FrameBuilder::Lbvh => self.bvh.record_build(ctx, encoder),
            FrameBuilder::Sah(options) => {
                let at = match self.sah.iter().position(|b| b.options() == options) {
                    Some(at) => at,
                    None => {
                        self.sah.push(GpuSahBuilder::new(ctx, &self.bvh, options)?);
                        self.sah.len() - 1
                    }
                };
                self.sah[at].record(ctx, &mut self.bvh, encoder);
            }
        }
        Ok(())
    }

    /// Records the SAH cost's reduction and read-back, if measured and none is on its way (always after a
    /// rebuild: a cost of the tree before it says nothing about the new one).
    fn record_cost(&mut self, ctx: &GpuContext, encoder: &mut wgpu::CommandEncoder, rebuilt: bool) {
        if let Some(costs) = &self.costs
            && (rebuilt || self.pending_cost.is_none())
        {
            let r = costs.record(ctx, encoder, &self.bvh);
            self.pending_cost = Some((r, rebuilt));
        }
    }
}
