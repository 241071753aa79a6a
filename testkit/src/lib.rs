//! What the workspace's tests share about the outside tools they need: a GPU adapter (Mesa's
//! software Vulkan driver will do), Xvfb, Chromium and Mitsuba 3. `scripts/test` installs all of
//! them on Debian and runs the tests; `cargo test --workspace` alone works wherever they are
//! already installed.
//!
//! A test never skips silently: a missing tool fails it with a message naming the command that
//! installs it ([`SETUP`]), unless the tool's `BOUNCE_ALLOW_NO_*` variable is `1` (CI never sets
//! one), where the test says on stderr that it skipped and returns.
//!
//! It also holds the fixtures more than one crate's tests use: the scenes in `assets/`
//! ([`cornell_gltf`]), and behind features the Cornell box as the server and client tests bake
//! it ([`fixtures::baked_cornell_box`], feature `bake`) and one GPU adapter a test binary
//! ([`fixtures::gpu_context`], feature `gpu`), and scenes written from the assets for one test's
//! need ([`scenes`], feature `scenes`).

use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::process::Command;

#[cfg(any(feature = "bake", feature = "gpu"))]
pub mod fixtures;
#[cfg(feature = "scenes")]
pub mod scenes;

/// The repository's `assets/` directory: the test scenes and their licences.
pub fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets")
}

/// The Cornell box every crate's tests light: `assets/cornell-box/scene.gltf`.
pub fn cornell_gltf() -> PathBuf {
    assets().join("cornell-box/scene.gltf")
}

/// The command that installs what the tests need and then runs them all (the README's second
/// command).
pub const SETUP: &str = "scripts/test";

/// An outside tool some tests need.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// A wgpu adapter: a real GPU, or lavapipe (Debian's `mesa-vulkan-drivers`).
    GpuAdapter,
    /// An X server for the viewer's window (Debian's `xvfb`).
    Xvfb,
    /// Headless Chromium for the browser tests (Debian's `chromium`).
    Chromium,
    /// Python 3 with Mitsuba 3, the outside renderer the reference and the render are checked
    /// against.
    Mitsuba,
}

impl Tool {
    /// The variable that, set to `1`, turns this tool's absence into a skip.
    pub fn allow_variable(self) -> &'static str {
        match self {
            // The window needs both, and a machine without one usually lacks the other.
            Tool::GpuAdapter | Tool::Xvfb => "BOUNCE_ALLOW_NO_GPU",
            Tool::Chromium => "BOUNCE_ALLOW_NO_BROWSER",
            Tool::Mitsuba => "BOUNCE_ALLOW_NO_MITSUBA",
        }
    }

    fn needs(self) -> &'static str {
        match self {
            Tool::GpuAdapter => {
                "a GPU adapter (Mesa's software Vulkan driver will do: Debian's mesa-vulkan-drivers)"
            }
            Tool::Xvfb => "Xvfb (Debian's xvfb) and the X11 client libraries",
            Tool::Chromium => "Chromium (Debian's chromium, or $BOUNCE_CHROMIUM)",
            Tool::Mitsuba => {
                "Python 3 with Mitsuba 3 (a virtual environment in the build directory, \
                 mitsuba-venv, or $BOUNCE_PYTHON)"
            }
        }
    }
}

/// The message a test fails with when `tool` is missing.
pub fn missing_message(tool: Tool, why: &dyn Display) -> String {
    format!(
        "this test needs {}, and it is missing: {why}\n\
         `{SETUP}` installs it (and everything else the tests need) and runs the tests; \
         or set {}=1 to skip the tests that need it",
        tool.needs(),
        tool.allow_variable()
    )
}

/// `tool` is missing (`why`): panics with [`missing_message`], unless the tool's
/// `BOUNCE_ALLOW_NO_*` variable is `1`, where it says so on stderr and returns `None`, and the
/// test returns.
#[track_caller]
pub fn missing<T>(tool: Tool, why: impl Display) -> Option<T> {
    let message = missing_message(tool, &why);
    if std::env::var(tool.allow_variable()).as_deref() == Ok("1") {
        eprintln!("SKIPPED ({}=1): {message}", tool.allow_variable());
        return None;
    }
    panic!("{message}");
}

/// The virtual environment `scripts/test` makes in the build directory.
pub const MITSUBA_VENV: &str = "mitsuba-venv";

/// The Python that runs Mitsuba: `$BOUNCE_PYTHON` (which `scripts/test` sets), else the
/// build directory's `mitsuba-venv` when there is one, else `python3` from `PATH`.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("BOUNCE_PYTHON").filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    std::env::current_exe()
        .ok()
        .and_then(|exe| venv_python_above(&exe))
        .unwrap_or_else(|| PathBuf::from("python3"))
}

/// The venv's interpreter in the build directory holding `exe`: a test binary is
/// `TARGET/<profile>/deps/NAME` (or `TARGET/<triple>/<profile>/deps/NAME`), so the build
/// directory is a few levels up; `$CARGO_TARGET_DIR` moves it, but not this relation.
fn venv_python_above(exe: &Path) -> Option<PathBuf> {
    exe.ancestors()
        .skip(1)
        .take(4)
        .map(|dir| dir.join(MITSUBA_VENV).join("bin").join("python3"))
        .find(|p| p.is_file())
}

/// [`python()`] when it can import Mitsuba. Otherwise [`missing`]: a panic naming [`SETUP`], or
/// `None` where `BOUNCE_ALLOW_NO_MITSUBA=1`.
#[track_caller]
pub fn mitsuba_python() -> Option<PathBuf> {
    let python = python();
    let probe = Command::new(&python)
        .args(["-c", "import mitsuba"])
        .output();
    match probe {
        Ok(out) if out.status.success() => Some(python),
        Ok(out) => missing(
            Tool::Mitsuba,
            format!(
                "{} cannot import mitsuba: {}",
                python.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        ),
        Err(e) => missing(Tool::Mitsuba, format!("running {}: {e}", python.display())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_message_names_the_setup_command_and_the_skip_variable() {
        for tool in [Tool::GpuAdapter, Tool::Xvfb, Tool::Chromium, Tool::Mitsuba] {
            let m = missing_message(tool, &"because");
            assert!(m.contains("`scripts/test` installs it"), "{m}");
            assert!(m.contains(&format!("{}=1", tool.allow_variable())), "{m}");
            assert!(m.contains("because"), "{m}");
        }
    }

    #[test]
    fn the_venv_is_found_above_a_test_binary() {
        let dir = std::env::temp_dir().join(format!("bounce-testkit-{}", std::process::id()));
        let bin = dir.join("target/debug/deps");
        let python = dir.join("target").join(MITSUBA_VENV).join("bin/python3");
        std::fs::create_dir_all(&bin).unwrap();
        let exe = bin.join("it-0123");
        assert_eq!(venv_python_above(&exe), None, "no venv yet");
        std::fs::create_dir_all(python.parent().unwrap()).unwrap();
        std::fs::write(&python, b"").unwrap();
        assert_eq!(venv_python_above(&exe), Some(python));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
