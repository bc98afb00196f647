//! Kernels compiled without floating-point contraction, so that the GPU rounds as the CPU does.
//!
//! WGSL says nothing about contraction, and SPIR-V lets a driver fuse a multiply and an add into one
//! `fma` unless the multiply is decorated `NoContraction`. Lavapipe never fuses; NVIDIA's driver does, and
//! a fused `a·b − c·d` is not the negation of `c·d − a·b`: the watertight triangle test's edge functions
//! then disagree between the two triangles of a shared edge (a ray slips through), the Dekker splits of
//! `ray_tests.wgsl` lose their exactness, and SAH costs and box centres round differently from the CPU's,
//! so trees built on the GPU stop matching the CPU's node for node. naga has no option for it, so on
//! Vulkan the crate compiles each kernel file to SPIR-V with naga itself, decorates every floating-point
//! multiply, add, subtract, negate, divide and dot product `NoContraction`, and hands the words to the
//! driver as a passthrough module ([`wgpu::Features::PASSTHROUGH_SHADERS`]). Elsewhere (Metal, DX12)
//! the WGSL goes through wgpu as usual.
//!
//! Cost: compiling the kernels once per device takes a few milliseconds more; the kernels themselves
//! run a multiply and an add where a fused multiply–add would do, which the bench's GPU rows measure.

use std::borrow::Cow;

/// The opcodes decorated: `OpFNegate`, `OpFAdd`, `OpFSub`, `OpFMul`, `OpFDiv`, `OpFRem`, `OpFMod`,
/// `OpVectorTimesScalar`, `OpMatrixTimesScalar`, `OpVectorTimesMatrix`, `OpMatrixTimesVector`,
/// `OpMatrixTimesMatrix`, `OpOuterProduct`, `OpDot` (all have their result id in word 2).
const ARITHMETIC: [u32; 14] = [
    127, 129, 131, 133, 136, 138, 141, 142, 143, 144, 145, 146, 147, 148,
];

/// `OpDecorate` and the `NoContraction` decoration.
const OP_DECORATE: u32 = 71;
const NO_CONTRACTION: u32 = 42;

/// Opcodes that may open the module's type, constant and global section, which annotations precede:
/// `OpTypeVoid` ..= `OpTypeForwardPointer`, the constants (`OpConstantTrue` ..= `OpSpecConstantOp`),
/// `OpVariable` and `OpFunction`.
fn opens_declarations(op: u32) -> bool {
    (19..=39).contains(&op) || (41..=52).contains(&op) || op == 59 || op == 54
}

/// `words` (a SPIR-V module) with an `OpDecorate %r NoContraction` for the result `%r` of every
/// floating-point arithmetic instruction, placed with the module's other annotations. `None` when the
/// words are not a module this understands (then the caller compiles the WGSL the ordinary way).
pub(crate) fn without_contraction(words: &[u32]) -> Option<Vec<u32>> {
    const HEADER: usize = 5;
    if words.len() < HEADER || words[0] != 0x0723_0203 {
        return None;
    }
    let mut results = Vec::new();
    let mut insert_at = None;
    let mut at = HEADER;
    while at < words.len() {
        let count = (words[at] >> 16) as usize;
        let op = words[at] & 0xffff;
        if count == 0 || at + count > words.len() {
            return None;
        }
        if insert_at.is_none() && opens_declarations(op) {
            insert_at = Some(at);
        }
        if ARITHMETIC.contains(&op) && count >= 4 {
            results.push(words[at + 2]);
        }
        at += count;
    }
    let insert_at = insert_at?;
    let mut out = Vec::with_capacity(words.len() + 3 * results.len());
    out.extend_from_slice(&words[..insert_at]);
    for r in results {
        out.extend_from_slice(&[(3 << 16) | OP_DECORATE, r, NO_CONTRACTION]);
    }
    out.extend_from_slice(&words[insert_at..]);
    Some(out)
}

/// A module's entry points: name and workgroup size.
type EntryPoints = Vec<(String, [u32; 3])>;

/// The WGSL `source` as a SPIR-V module without contraction, with its entry points, or an error message.
fn spirv(source: &str) -> Result<(Vec<u32>, EntryPoints), String> {
    use naga::back::spv;
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .map_err(|e| format!("{e:?}"))?;
    let options = spv::Options {
        lang_version: (1, 3),
        bounds_check_policies: naga::proc::BoundsCheckPolicies {
            index: naga::proc::BoundsCheckPolicy::Restrict,
            buffer: naga::proc::BoundsCheckPolicy::Restrict,
            image_load: naga::proc::BoundsCheckPolicy::Restrict,
            binding_array: naga::proc::BoundsCheckPolicy::Unchecked,
        },
        zero_initialize_workgroup_memory: spv::ZeroInitializeWorkgroupMemoryMode::Polyfill,
        force_loop_bounding: true,
        ..spv::Options::default()
    };
    let words = spv::write_vec(&module, &info, &options, None).map_err(|e| e.to_string())?;
    let words = without_contraction(&words).ok_or("naga wrote SPIR-V this pass cannot read")?;
    let entries = module
        .entry_points
        .iter()
        .map(|e| (e.name.clone(), e.workgroup_size))
        .collect();
    Ok((words, entries))
}

/// Compiles one kernel file: without contraction where the device takes passthrough SPIR-V (Vulkan),
/// else through wgpu's own WGSL path. A kernel naga cannot compile here falls back to the WGSL path too,
/// logged, so a shader error is still reported by wgpu's validation. The flag: compiled without
/// contraction.
pub(crate) fn shader_module(
    device: &wgpu::Device,
    name: &str,
    source: &str,
) -> (wgpu::ShaderModule, bool) {
    if device
        .features()
        .contains(wgpu::Features::PASSTHROUGH_SHADERS)
    {
        match spirv(source) {
            Ok((words, entries)) => {
                let entry_points: Vec<wgpu::PassthroughShaderEntryPoint> = entries
                    .iter()
                    .map(|(n, [x, y, z])| wgpu::PassthroughShaderEntryPoint {
                        name: Cow::Borrowed(n.as_str()),
                        workgroup_size: (*x, *y, *z),
                    })
                    .collect();
                let desc = wgpu::ShaderModuleDescriptorPassthrough {
                    label: Some(name),
                    entry_points: Cow::Owned(entry_points),
                    spirv: Some(Cow::Owned(words)),
                    ..Default::default()
                };
                // SAFETY: the words are naga's own validated output for this WGSL, with bounds checks
                // (`Restrict`), zero-initialised workgroup memory and bounded loops as wgpu would compile
                // it; the only change is the added `NoContraction` decorations, which are valid on
                // these instructions and restrict the driver's freedom rather than widen it.
                return (
                    unsafe { device.create_shader_module_passthrough(desc) },
                    true,
                );
            }
            Err(e) => log::warn!("kinetrace: kernel {name} compiled through wgpu instead: {e}"),
        }
    }
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    (module, false)
}

/// Test hook (feature `testing`): `a[i] / b[i]` by the kernels' correctly rounded division (`div_rn` in
/// shaders/common.wgsl), read back, blocking. Equals the CPU's `a[i] / b[i]` bit for bit wherever the
/// quotient is zero or a finite normal number.
#[cfg(feature = "testing")]
pub fn divide(ctx: &super::GpuContext, a: &[f32], b: &[f32]) -> crate::Result<Vec<f32>> {
    pairs(ctx, "divide", a, b)
}

/// Test hook (feature `testing`): `√x[i]` by the kernels' correctly rounded square root, corrected from
/// the guess `guess[i]` (`sqrt_from` in shaders/common.wgsl; a NaN guess: the driver's root, `sqrt_rn`), read
/// back, blocking. Equals the CPU's `x[i].sqrt()` bit for bit for every `x[i]` from 2⁻¹⁰⁰ to 2¹²⁶ whose
/// guess lies within eight floats of its root (where subnormals are kept: see `sqrt_from`).
#[cfg(feature = "testing")]
pub fn square_root(ctx: &super::GpuContext, x: &[f32], guess: &[f32]) -> crate::Result<Vec<f32>> {
    pairs(ctx, "root", x, guess)
}

/// Runs test kernel `entry` of shaders/divide.wgsl over the pairs `(a[i], b[i])`, read back, blocking.
#[cfg(feature = "testing")]
fn pairs(ctx: &super::GpuContext, entry: &str, a: &[f32], b: &[f32]) -> crate::Result<Vec<f32>> {
    use super::buffers::{GpuBuffer, bind_group};
    assert_eq!(a.len(), b.len(), "one operand for another");
    let bytes = (a.len().max(1) * 4) as u64;
    let (na, nb, q) = (
        GpuBuffer::storage(ctx, "divide num", bytes),
        GpuBuffer::storage(ctx, "divide den", bytes),
        GpuBuffer::storage(ctx, "divide quot", (a.len() * 4) as u64),
    );
    na.write(ctx, a);
    nb.write(ctx, b);
    let module = &ctx.kernels.divide;
    let group = bind_group(
        ctx,
        &module.layout,
        &[
            na.buffer().as_entire_binding(),
            nb.buffer().as_entire_binding(),
            q.buffer().as_entire_binding(),
        ],
    );
    let mut enc = ctx.encoder();
    if !a.is_empty() {
        let (x, y) = ctx.groups(a.len() as u32, 256);
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(module.pipeline(entry));
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
    let out = super::Readback::<f32>::record(ctx, &mut enc, q.buffer(), a.len());
    ctx.submit(enc);
    out.wait(ctx)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A multiply–add kernel: its `OpFMul` and `OpFAdd` results are decorated, once each, before the
    /// first type declaration, and nothing else changes.
    #[test]
    fn every_float_multiply_and_add_is_decorated() {
        let src = "@group(0) @binding(0) var<storage, read_write> x: array<f32>;\n\
                   @compute @workgroup_size(1) fn main() { x[0] = x[1] * x[2] + x[3]; }";
        let (words, entries) = spirv(src).unwrap();
        assert_eq!(entries, vec![("main".to_string(), [1, 1, 1])]);
        let mut at = 5;
        let (mut decorated, mut arithmetic, mut first_type) = (Vec::new(), Vec::new(), None);
        while at < words.len() {
            let (count, op) = ((words[at] >> 16) as usize, words[at] & 0xffff);
            if op == OP_DECORATE && words[at + 2] == NO_CONTRACTION {
                assert!(first_type.is_none(), "decoration after the declarations");
                decorated.push(words[at + 1]);
            }
            if op == 19 && first_type.is_none() {
                first_type = Some(at);
            }
            if op == 129 || op == 133 {
                arithmetic.push(words[at + 2]);
            }
            at += count;
        }
        assert_eq!(arithmetic.len(), 2);
        decorated.sort_unstable();
        arithmetic.sort_unstable();
        assert_eq!(decorated, arithmetic);
    }

    #[test]
    fn words_that_are_not_a_module_are_refused() {
        assert_eq!(without_contraction(&[1, 2, 3]), None);
        assert_eq!(without_contraction(&[0x0723_0203, 0, 0, 9, 0, 0]), None);
    }
}
