//! The Rust mirror of the shaders' shared declarations matches what naga reads from the WGSL:
//! `Params`'s size and member offsets, the work split constants, and the one `GpuLight` the
//! direct-light kernels and the renderer share (with its kind constants), the direct-light
//! kernels' own structs, and the near-field pass's `NearParams`.

use bounce_engine::gpu::{CHUNK, CHUNKS, Params, ROWS, TILE_ROWS, TILE_SETS, sources};
use naga::{Expression, Literal, Module, TypeInner};

fn parse(name: &str, source: &str) -> Module {
    naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)))
}

fn all_sources() -> [(&'static str, String); 5] {
    [
        ("dense", sources::dense_source()),
        ("logblock", sources::logblock_source()),
        ("sparse", sources::sparse_source()),
        ("dense tiled", sources::dense_tiled_source()),
        ("logblock tiled", sources::logblock_tiled_source()),
    ]
}

/// The matrix-vector sources, compiled for each chunk up to CHUNK.
fn row_sources() -> [(&'static str, String); 3] {
    [
        ("dense", sources::dense_source()),
        ("logblock", sources::logblock_source()),
        ("sparse", sources::sparse_source()),
    ]
}

#[test]
fn params_layout_matches_wgsl() {
    let rust: [(&str, usize); 13] = [
        ("n", std::mem::offset_of!(Params, n)),
        ("channels", std::mem::offset_of!(Params, channels)),
        ("sets", std::mem::offset_of!(Params, sets)),
        ("groups_x", std::mem::offset_of!(Params, groups_x)),
        ("nnz", std::mem::offset_of!(Params, nnz)),
        ("row0", std::mem::offset_of!(Params, row0)),
        ("rows", std::mem::offset_of!(Params, rows)),
        ("tile", std::mem::offset_of!(Params, tile)),
        ("lit", std::mem::offset_of!(Params, lit)),
        ("pad0", std::mem::offset_of!(Params, pad)),
        ("pad1", std::mem::offset_of!(Params, pad) + 4),
        ("pad2", std::mem::offset_of!(Params, pad) + 8),
        ("max", std::mem::offset_of!(Params, max)),
    ];
    for (name, source) in all_sources() {
        let module = parse(name, &source);
        let (members, span) = module
            .types
            .iter()
            .find_map(|(_, ty)| match (&ty.name, &ty.inner) {
                (Some(n), TypeInner::Struct { members, span }) if n == "Params" => {
                    Some((members.clone(), *span))
                }
                _ => None,
            })
            .unwrap_or_else(|| panic!("{name}: no struct Params"));
        assert_eq!(span as usize, std::mem::size_of::<Params>(), "{name}: size");
        let wgsl: Vec<(String, usize)> = members
            .iter()
            .map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize))
            .collect();
        let rust: Vec<(String, usize)> = rust.iter().map(|(n, o)| (n.to_string(), *o)).collect();
        assert_eq!(wgsl, rust, "{name}: members and offsets");
    }
}

fn constant(module: &Module, name: &str) -> u32 {
    let c = module
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no const {name}"))
        .1;
    match module.global_expressions[c.init] {
        Expression::Literal(Literal::U32(v)) => v,
        ref other => panic!("const {name} is {other:?}"),
    }
}

#[test]
fn work_split_constants_match_wgsl() {
    assert_eq!(
        CHUNKS,
        [1, 4, CHUNK, TILE_SETS],
        "the matrix-vector chunks, then the tiled kernel's"
    );
    for (name, source) in row_sources() {
        for chunk in CHUNKS.into_iter().filter(|&c| c <= CHUNK) {
            let variant = sources::with_chunk(&source, chunk);
            let module = parse(name, &variant);
            assert_eq!(constant(&module, "ROWS"), ROWS, "{name}");
            assert_eq!(
                constant(&module, "CHUNK"),
                chunk,
                "{name} compiled for {chunk}"
            );
            assert_eq!(constant(&module, "SLOTS"), ROWS * chunk, "{name}");
            // The reduction buffer holds WG * LANES values and a round covers LANES slots.
            let lanes = constant(&module, "LANES");
            assert_eq!(
                constant(&module, "WG") % 2,
                0,
                "{name}: WG halves down to 1"
            );
            assert!(
                (ROWS * chunk).is_multiple_of(lanes),
                "{name}: rounds cover the slots"
            );
            if name == "sparse" {
                let padded = constant(&module, "PADDED");
                assert!(
                    padded >= lanes && padded >= chunk && padded.is_multiple_of(lanes),
                    "{name}"
                );
            }
        }
    }
}

fn array_len(module: &Module, name: &str) -> u32 {
    let var = module
        .global_variables
        .iter()
        .find(|(_, v)| v.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no var {name}"))
        .1;
    match module.types[var.ty].inner {
        TypeInner::Array {
            size: naga::ArraySize::Constant(len),
            ..
        } => len.get(),
        ref other => panic!("var {name} is {other:?}"),
    }
}

/// The tiled kernel's split: the host dispatches `rows / TILE_ROWS` workgroups per chunk of
/// TILE_SETS sets, the threads cover the tile exactly, each step's loads are whole rounds of the
/// workgroup, and the workgroup tiles hold a step.
#[test]
fn tiled_split_constants_match_wgsl() {
    for (name, source) in [
        ("dense tiled", sources::dense_tiled_source()),
        ("logblock tiled", sources::logblock_tiled_source()),
    ] {
        let module = parse(name, &source);
        let c = |n| constant(&module, n);
        assert_eq!(c("CHUNK"), TILE_SETS, "{name}");
        assert_eq!(c("TM"), TILE_ROWS, "{name}");
        assert_eq!(c("RM"), 4, "{name}: a thread's rows are one vec4");
        assert_eq!(c("RS"), 4, "{name}: a thread's sets are one vec4");
        assert_eq!(
            (c("TM") / c("RM")) * (c("CHUNK") / c("RS")),
            c("TWG"),
            "{name}: one thread per RM x RS of the tile"
        );
        assert_eq!(c("TM") * c("TK") % c("TWG"), 0, "{name}: matrix loads");
        assert_eq!(c("CHUNK") * c("TK") % c("TWG"), 0, "{name}: light loads");
        assert_eq!(
            array_len(&module, "a_tile"),
            3 * c("TK") * c("ROW_GROUPS"),
            "{name}"
        );
        assert_eq!(
            array_len(&module, "b_tile"),
            3 * c("TK") * c("SET_GROUPS"),
            "{name}"
        );
        let entry = module
            .entry_points
            .iter()
            .find(|e| e.name == "matvec_tiled")
            .unwrap_or_else(|| panic!("{name}: no matvec_tiled"));
        assert_eq!(entry.workgroup_size, [c("TWG"), 1, 1], "{name}");
    }
}

/// The tensor-core kernel's constants agree with its host (`TILE_ROWS` rows × `TILE_SETS` sets a
/// workgroup, eight 32-wide subgroups of 16 rows × 32 sets each, 16-deep steps), and naga
/// validates it with the capabilities the host requests and writes it as SPIR-V. No adapter
/// here may run it (lavapipe has no cooperative matrices), so this is what CI can check of it;
/// the GPU tests run it wherever the device has tensor cores.
#[test]
fn tensor_kernel_compiles_and_matches_its_host() {
    let source = sources::tensor_source();
    let module = parse("tensor", &source);
    let c = |n| constant(&module, n);
    assert_eq!(c("CHUNK"), TILE_SETS);
    assert_eq!(c("TT"), TILE_ROWS);
    assert_eq!(
        c("TT"),
        c("CHUNK"),
        "square tiles: one subgroup layout for rows and sets"
    );
    assert_eq!(c("TWG"), 256);
    // 8 subgroups × (16 rows × 2 sixteen-set blocks) cover the 64 × 64 tile once.
    assert_eq!((c("TT") / 16) * (c("CHUNK") / 32), c("TWG") / 32);
    assert_eq!(c("TK") % 16, 0, "a step is whole 16-deep products");
    assert_eq!(c("TT") * c("TK") % c("TWG"), 0, "decode loads");
    assert_eq!(array_len(&module, "a_tile"), 3 * c("TT") * c("TK"));
    assert_eq!(array_len(&module, "c_tile"), c("TT") * c("CHUNK"));
    for (entry, size) in [
        ("light_top_of", 256),
        ("light_pack", 256),
        ("matvec_tensor", c("TWG")),
    ] {
        let e = module
            .entry_points
            .iter()
            .find(|e| e.name == entry)
            .unwrap_or_else(|| panic!("no {entry}"));
        assert_eq!(e.workgroup_size, [size, 1, 1], "{entry}");
    }
    use naga::valid::{Capabilities, ValidationFlags, Validator};
    let caps =
        Capabilities::SHADER_FLOAT16 | Capabilities::SUBGROUP | Capabilities::COOPERATIVE_MATRIX;
    let info = Validator::new(ValidationFlags::all(), caps)
        .validate(&module)
        .unwrap_or_else(|e| panic!("tensor: {}", e.emit_to_string(&source)));
    // Without the capability the same module is refused: the check above is not vacuous.
    assert!(
        Validator::new(
            ValidationFlags::all(),
            caps - Capabilities::COOPERATIVE_MATRIX
        )
        .validate(&module)
        .is_err()
    );
    for bc4 in [0.0, 1.0] {
        let constants = std::iter::once(("BC4".to_string(), bc4)).collect();
        let (module, info) =
            naga::back::pipeline_constants::process_overrides(&module, &info, None, &constants)
                .unwrap_or_else(|e| panic!("tensor, BC4 = {bc4}: {e}"));
        let words =
            naga::back::spv::write_vec(&module, &info, &naga::back::spv::Options::default(), None)
                .unwrap_or_else(|e| panic!("tensor SPIR-V, BC4 = {bc4}: {e}"));
        // OpCooperativeMatrixMulAddKHR (4459), once per accumulator a step.
        let muladds = spirv_ops(&words).filter(|&op| op == 4459).count();
        assert_eq!(muladds, 6, "six 16 x 16 accumulators a subgroup");
    }
}

/// The opcodes of a SPIR-V module's instructions, after its five-word header.
fn spirv_ops(words: &[u32]) -> impl Iterator<Item = u32> + '_ {
    let mut at = 5;
    std::iter::from_fn(move || {
        let word = *words.get(at)?;
        at += (word >> 16).max(1) as usize;
        Some(word & 0xffff)
    })
}

/// A struct's size and `(member, offset)` list as naga lays it out in `source`.
fn wgsl_struct(source_name: &str, source: &str, name: &str) -> (usize, Vec<(String, usize)>) {
    let module = parse(source_name, source);
    module
        .types
        .iter()
        .find_map(|(_, ty)| match (&ty.name, &ty.inner) {
            (Some(n), TypeInner::Struct { members, span }) if n == name => Some((
                *span as usize,
                members
                    .iter()
                    .map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize))
                    .collect(),
            )),
            _ => None,
        })
        .unwrap_or_else(|| panic!("{source_name}: no struct {name}"))
}

fn named(list: &[(&str, usize)]) -> Vec<(String, usize)> {
    list.iter().map(|(n, o)| (n.to_string(), *o)).collect()
}

/// The one guard of the one `GpuLight`: the direct-light kernels and bounce-render's shading
/// all prepend `light::WGSL`, so its struct is the only WGSL `GpuLight` there is.
#[test]
fn gpu_light_matches_wgsl() {
    use bounce_engine::gpu::light::{GpuLight, KIND_DIRECTIONAL, KIND_POINT, KIND_SPOT, WGSL};
    use std::mem::{offset_of, size_of};

    let (size, members) = wgsl_struct("light", WGSL, "GpuLight");
    assert_eq!(
        size,
        size_of::<GpuLight>(),
        "GpuLight size (the array stride)"
    );
    assert_eq!(
        members,
        named(&[
            ("position", offset_of!(GpuLight, position)),
            ("kind", offset_of!(GpuLight, kind)),
            ("axis", offset_of!(GpuLight, axis)),
            ("inv_range", offset_of!(GpuLight, inv_range)),
            ("radiant", offset_of!(GpuLight, radiant)),
            ("angle_scale", offset_of!(GpuLight, angle_scale)),
            ("angle_offset", offset_of!(GpuLight, angle_offset)),
            ("first_view", offset_of!(GpuLight, first_view)),
            ("pad0", offset_of!(GpuLight, pad)),
            ("pad1", offset_of!(GpuLight, pad) + 4),
        ])
    );

    let module = parse("light", WGSL);
    assert_eq!(constant(&module, "KIND_DIRECTIONAL"), KIND_DIRECTIONAL);
    assert_eq!(constant(&module, "KIND_POINT"), KIND_POINT);
    assert_eq!(constant(&module, "KIND_SPOT"), KIND_SPOT);
}

#[test]
fn direct_structs_match_wgsl() {
    use bounce_engine::gpu::{DIRECT_WG, DirectParams, GpuPatch};
    use std::mem::{offset_of, size_of};
    let source = sources::direct_source();

    let (size, members) = wgsl_struct("direct", &source, "DirectParams");
    assert_eq!(size, size_of::<DirectParams>(), "DirectParams size");
    assert_eq!(
        members,
        named(&[
            ("n", offset_of!(DirectParams, n)),
            ("sets", offset_of!(DirectParams, sets)),
            ("side", offset_of!(DirectParams, side)),
            ("groups_x", offset_of!(DirectParams, groups_x)),
            ("dims", offset_of!(DirectParams, dims)),
            ("voxel_size", offset_of!(DirectParams, voxel_size)),
            ("origin", offset_of!(DirectParams, origin)),
            ("pad", offset_of!(DirectParams, pad)),
        ])
    );

    let (size, members) = wgsl_struct("direct", &source, "GpuPatch");
    assert_eq!(
        size,
        size_of::<GpuPatch>(),
        "GpuPatch size (the array stride)"
    );
    assert_eq!(
        members,
        named(&[
            ("face", offset_of!(GpuPatch, face)),
            ("plane", offset_of!(GpuPatch, plane)),
            ("lo0", offset_of!(GpuPatch, lo)),
            ("lo1", offset_of!(GpuPatch, lo) + 4),
            ("hi0", offset_of!(GpuPatch, hi)),
            ("hi1", offset_of!(GpuPatch, hi) + 4),
            ("cell_x", offset_of!(GpuPatch, cell)),
            ("cell_y", offset_of!(GpuPatch, cell) + 4),
            ("cell_z", offset_of!(GpuPatch, cell) + 8),
        ])
    );

    assert_eq!(constant(&parse("direct", &source), "WG"), DIRECT_WG);
}

#[test]
fn direct_surface_structs_match_wgsl() {
    use bounce_core::trimesh::{MeshNode, MeshTri};
    use bounce_engine::gpu::{GpuSample, SURFACE_STACK, SURFACE_WG, SurfaceParams};
    use std::mem::{offset_of, size_of};
    let source = sources::direct_surface_source();

    let (size, members) = wgsl_struct("direct_surface", &source, "SurfaceParams");
    assert_eq!(size, size_of::<SurfaceParams>(), "SurfaceParams size");
    assert_eq!(
        members,
        named(&[
            ("n", offset_of!(SurfaceParams, n)),
            ("per_patch", offset_of!(SurfaceParams, per_patch)),
            ("count", offset_of!(SurfaceParams, count)),
            ("lights", offset_of!(SurfaceParams, lights)),
            ("first", offset_of!(SurfaceParams, first)),
            ("patches", offset_of!(SurfaceParams, patches)),
            ("sets", offset_of!(SurfaceParams, sets)),
            ("nodes", offset_of!(SurfaceParams, nodes)),
            ("averaged", offset_of!(SurfaceParams, averaged)),
            ("pilots", offset_of!(SurfaceParams, pilots)),
            ("pad1", offset_of!(SurfaceParams, pad)),
            ("pad2", offset_of!(SurfaceParams, pad) + 4),
        ])
    );

    let (size, members) = wgsl_struct("direct_surface", &source, "Tri");
    assert_eq!(size, size_of::<MeshTri>(), "Tri size (the array stride)");
    assert_eq!(
        members,
        named(&[
            ("p0", offset_of!(MeshTri, p0)),
            ("source", offset_of!(MeshTri, source)),
            ("e1", offset_of!(MeshTri, e1)),
            ("double_sided", offset_of!(MeshTri, double_sided)),
            ("e2", offset_of!(MeshTri, e2)),
            ("pad", offset_of!(MeshTri, pad)),
        ])
    );

    let (size, members) = wgsl_struct("direct_surface", &source, "Node");
    assert_eq!(size, size_of::<MeshNode>(), "Node size (the array stride)");
    assert_eq!(
        members,
        named(&[
            ("min", offset_of!(MeshNode, min)),
            ("prim_count", offset_of!(MeshNode, prim_count)),
            ("max", offset_of!(MeshNode, max)),
            ("first_index", offset_of!(MeshNode, first_index)),
        ])
    );

    let (size, members) = wgsl_struct("direct_surface", &source, "GpuSample");
    assert_eq!(
        size,
        size_of::<GpuSample>(),
        "GpuSample size (the array stride)"
    );
    assert_eq!(
        members,
        named(&[
            ("position", offset_of!(GpuSample, position)),
            ("pad0", offset_of!(GpuSample, pad0)),
            ("normal", offset_of!(GpuSample, normal)),
            ("pad1", offset_of!(GpuSample, pad1)),
        ])
    );

    let module = parse("direct_surface", &source);
    assert_eq!(constant(&module, "WG"), SURFACE_WG);
    assert_eq!(constant(&module, "STACK"), SURFACE_STACK);
    // One `shadow` workgroup writes whole words of visibility bits.
    assert_eq!(constant(&module, "WORDS") * 32, SURFACE_WG);
}

#[test]
fn bandwidth_probe_layout_matches_wgsl() {
    use bounce_engine::gpu::bandwidth::Probe;
    let source = sources::bandwidth_source();
    let module = parse("bandwidth", source);
    let (members, span) = module
        .types
        .iter()
        .find_map(|(_, ty)| match (&ty.name, &ty.inner) {
            (Some(n), TypeInner::Struct { members, span }) if n == "Probe" => {
                Some((members.clone(), *span))
            }
            _ => None,
        })
        .expect("struct Probe");
    assert_eq!(span as usize, std::mem::size_of::<Probe>());
    let wgsl: Vec<(String, usize)> = members
        .iter()
        .map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize))
        .collect();
    let rust = vec![
        ("len".to_string(), std::mem::offset_of!(Probe, len)),
        ("groups".to_string(), std::mem::offset_of!(Probe, groups)),
    ];
    assert_eq!(wgsl, rust);
}

#[test]
fn near_field_params_match_wgsl() {
    use bounce_engine::gpu::{NEAR_WG, NearParams};
    use std::mem::{offset_of, size_of};
    let source = sources::near_field_source();

    let (size, members) = wgsl_struct("near_field", source, "NearParams");
    assert_eq!(size, size_of::<NearParams>(), "NearParams size");
    assert_eq!(
        members,
        named(&[
            ("n", offset_of!(NearParams, n)),
            ("sets", offset_of!(NearParams, sets)),
            ("per_row", offset_of!(NearParams, per_row)),
            ("averaged", offset_of!(NearParams, averaged)),
        ])
    );
    assert_eq!(constant(&parse("near_field", source), "NEAR_WG"), NEAR_WG);
}
