//! The repository stands alone: no file in it reads, or points a reader at, the project's shared
//! folder beside the checkout (its scenes, the thesis, the old design notes). Scenes live in
//! `assets/`, the design in `docs/design.md`; a clone anywhere must need nothing else.

use std::path::{Path, PathBuf};

/// What a path out of the repository to the shared folder looks like. Built from pieces, so that
/// this file does not match itself.
fn patterns() -> Vec<String> {
    let shared = "shared";
    vec![
        format!("../{shared}"),
        format!("{shared}/scenes"),
        format!("{shared}/seed"),
        format!("{shared}/DESIGN"),
    ]
}

/// Every file under `dir` but build output (any folder cargo marks with CACHEDIR.TAG, wherever
/// CARGO_TARGET_DIR put it, and `target/`), git's own folder and vendored third-party code.
fn files(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let path = entry.unwrap().path();
        if path.is_dir() {
            let skipped = [".git", "target", "node_modules"]
                .iter()
                .any(|name| path.file_name().is_some_and(|n| n == *name))
                || path.join("CACHEDIR.TAG").exists()
                || path == root.join("web/public/vendor");
            if !skipped {
                files(root, &path, out);
            }
        } else if path.is_file() {
            out.push(path);
        }
    }
}

/// `path:line: text` for each line of `bytes` holding one of `patterns`.
fn hits(path: &Path, bytes: &[u8], patterns: &[String]) -> Vec<String> {
    let text = String::from_utf8_lossy(bytes);
    text.lines()
        .enumerate()
        .filter(|(_, line)| patterns.iter().any(|p| line.contains(p.as_str())))
        .map(|(i, line)| format!("{}:{}: {}", path.display(), i + 1, line.trim()))
        .collect()
}

#[test]
fn nothing_in_the_repository_points_outside_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let root = root.canonicalize().expect("the repository's root");
    let mut all = Vec::new();
    files(&root, &root, &mut all);
    // The walk must see the repository, or the check below proves nothing.
    for expected in ["README.md", "core/src/lib.rs", "docs/design.md", ".ci/run"] {
        assert!(
            all.contains(&root.join(expected)),
            "the walk missed {expected}"
        );
    }
    let patterns = patterns();
    let found: Vec<String> = all
        .iter()
        .flat_map(|path| {
            let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            hits(path.strip_prefix(&root).unwrap_or(path), &bytes, &patterns)
        })
        .collect();
    assert!(
        found.is_empty(),
        "files point outside the repository (copy what they need into it: scenes into assets/, \
         design notes into docs/design.md):\n{}",
        found.join("\n")
    );
}

#[test]
fn the_check_sees_each_pattern() {
    let patterns = patterns();
    for p in &patterns {
        let line = format!("let x = Path::new(\"{p}/file\");\n");
        assert_eq!(hits(Path::new("x.rs"), line.as_bytes(), &patterns).len(), 1);
    }
    let clean = b"assets/pandora/pandora.glb\ndocs/design.md\n";
    assert!(hits(Path::new("x.rs"), clean, &patterns).is_empty());
}
