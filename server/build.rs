//! Writes the table of the web client's files (`web/public/`), which the server embeds and serves
//! (`src/http/web.rs`). The protobuf code is `bounce-wire`'s.

use std::path::{Path, PathBuf};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    write_web_table(&out)?;
    Ok(())
}

/// `web_files.rs` in `out`: `WEB_FILES`, every file under `web/public/` as
/// `(path relative to it with '/' separators, include_bytes!(its absolute path))`, sorted by path.
/// Cargo is told to rerun when any directory or file of the tree changes, so a file the page's
/// author adds is picked up by the next build. A missing directory gives an empty table.
fn write_web_table(out: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR")?).join("../web/public");
    println!("cargo:rerun-if-changed={}", root.display());
    let mut files = Vec::new();
    if root.is_dir() {
        collect(&root, &root, &mut files)?;
    }
    files.sort();
    let mut table = String::from("pub(crate) static WEB_FILES: &[(&str, &[u8])] = &[\n");
    for (rel, abs) in &files {
        // `{:?}` writes a Rust string literal, escapes included.
        table.push_str(&format!("    ({rel:?}, include_bytes!({abs:?})),\n"));
    }
    table.push_str("];\n");
    std::fs::write(out.join("web_files.rs"), table)?;
    Ok(())
}

fn collect(
    root: &Path,
    dir: &Path,
    files: &mut Vec<(String, String)>,
) -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed={}", dir.display());
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.is_dir() {
            collect(root, &path, files)?;
        } else if path.is_file() {
            println!("cargo:rerun-if-changed={}", path.display());
            let rel = path.strip_prefix(root)?;
            let parts: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            let abs = path.canonicalize()?;
            files.push((parts.join("/"), abs.to_string_lossy().into_owned()));
        }
    }
    Ok(())
}
