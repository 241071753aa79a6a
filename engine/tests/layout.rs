//! The Rust mirror of the shaders' shared declarations matches what naga reads from the WGSL:
//! `Params`'s size and member offsets, and the work split constants.

use bounce_engine::gpu::{CHUNK, Params, ROWS, sources};
use naga::{Expression, Literal, Module, TypeInner};

fn parse(name: &str, source: &str) -> Module {
    naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)))
}

fn all_sources() -> [(&'static str, String); 3] {
    [
        ("dense", sources::dense_source()),
        ("logblock", sources::logblock_source()),
        ("sparse", sources::sparse_source()),
    ]
}

#[test]
fn params_layout_matches_wgsl() {
    let rust: [(&str, usize); 9] = [
        ("n", std::mem::offset_of!(Params, n)),
        ("channels", std::mem::offset_of!(Params, channels)),
        ("sets", std::mem::offset_of!(Params, sets)),
        ("groups_x", std::mem::offset_of!(Params, groups_x)),
        ("nnz", std::mem::offset_of!(Params, nnz)),
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
    for (name, source) in all_sources() {
        let module = parse(name, &source);
        assert_eq!(constant(&module, "ROWS"), ROWS, "{name}");
        assert_eq!(constant(&module, "CHUNK"), CHUNK, "{name}");
        assert_eq!(constant(&module, "SLOTS"), ROWS * CHUNK, "{name}");
        // The reduction buffer holds WG * LANES values and a round covers LANES slots.
        assert_eq!(
            constant(&module, "WG") % 2,
            0,
            "{name}: WG halves down to 1"
        );
        assert_eq!(CHUNK % constant(&module, "LANES"), 0, "{name}");
    }
}
