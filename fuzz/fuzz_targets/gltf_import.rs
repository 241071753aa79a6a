//! The glTF importer on arbitrary bytes (a `.glb`, or a `.gltf`'s JSON), with everything a bake
//! and a server do with one: the import with shading (a superset of the bake's import), and the
//! packing of the model that a baked file keeps and a server serves.
//!
//! The URIs the input names resolve beneath a temporary directory made for this process, which
//! holds a buffer and small images the fuzzer can reach by name (`scene.bin`, `tex.png`,
//! `textures/tex.png`), and a symbolic link out of it (`link.bin`).
//! Beside that directory, outside it, lies a secret file of random bytes; a packed model that
//! contains them means a URI escaped the directory, and the target panics. A packed model of a
//! scene that imports (as a bake packs only such scenes) must also pass the check a server makes
//! before serving one.
#![no_main]

use std::hash::{BuildHasher, Hasher};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use bounce_core::import::{ImportOptions, import_slice_with, pack_bytes, validate_packed};
use libfuzzer_sys::fuzz_target;

/// A 1×1 RGB PNG, for `tex.png` in the sandbox.
const PNG_1X1: &[u8] = &[
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x02, 0x00, 0x00, 0x00, 0x90, 0x77, 0x53,
    0xde, 0x00, 0x00, 0x00, 0x0c, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0xf8, 0xdf, 0xc0, 0x00,
    0x00, 0x04, 0x01, 0x01, 0x80, 0xc5, 0x2a, 0x18, 0x5d, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e,
    0x44, 0xae, 0x42, 0x60, 0x82,
];

/// The buffer `assets/cornell-box/scene.gltf` names.
const CORNELL_BIN: &[u8] = include_bytes!("../../assets/cornell-box/scene.bin");

struct Sandbox {
    /// Kept so the directory lives as long as the process.
    _dir: tempfile::TempDir,
    /// The glTF's own directory: the only place its URIs may reach.
    base: PathBuf,
    /// The bytes of `secret.bin`, beside `base`.
    secret: Vec<u8>,
}

fn sandbox() -> &'static Sandbox {
    static SANDBOX: OnceLock<Sandbox> = OnceLock::new();
    SANDBOX.get_or_init(|| {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let base = dir.path().join("scene");
        std::fs::create_dir(&base).expect("the scene directory");
        // 4 KiB the input cannot contain: random per process, so no seed or mutation holds them.
        let state = std::collections::hash_map::RandomState::new();
        let secret: Vec<u8> = (0..512u64)
            .flat_map(|i| {
                let mut h = state.build_hasher();
                h.write_u64(i);
                h.finish().to_le_bytes()
            })
            .collect();
        std::fs::write(dir.path().join("secret.bin"), &secret).expect("secret.bin");
        // The Cornell box's own buffer, so its committed seed (`scene.gltf` naming `scene.bin`)
        // imports whole.
        std::fs::write(base.join("scene.bin"), CORNELL_BIN).expect("scene.bin");
        std::fs::write(base.join("tex.png"), PNG_1X1).expect("tex.png");
        std::fs::create_dir(base.join("textures")).expect("textures/");
        std::fs::write(base.join("textures/tex.png"), PNG_1X1).expect("textures/tex.png");
        std::os::unix::fs::symlink(dir.path().join("secret.bin"), base.join("link.bin"))
            .expect("link.bin");
        Sandbox {
            _dir: dir,
            base,
            secret,
        }
    })
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

fuzz_target!(|data: &[u8]| {
    let sandbox = sandbox();
    let base = Some(sandbox.base.as_path());
    let imported = import_slice_with(data, base, &ImportOptions { shading: true }).is_ok();
    if let Ok(glb) = pack_bytes(data, base, Path::new("fuzz.gltf")) {
        assert!(
            !contains(&glb, &sandbox.secret),
            "a URI read a file outside the glTF's directory"
        );
        // What a bake packs, a server must accept (pack_bytes checks it; this checks the
        // check, on the scenes a bake packs: those that import).
        if imported && let Err(e) = validate_packed(&glb) {
            panic!("pack_bytes made a model the server would refuse: {e}");
        }
    }
});
