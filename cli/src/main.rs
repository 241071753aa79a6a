//! `bounce`: the command line of the bounce lighting service.
//!
//! This binary is glue: it owns argument parsing, terminal output and exit codes; the work itself
//! lives in the libraries (`bounce-core` bakes, `bounce-engine` relights, `bounce-server` serves
//! through `bounce_server::run`, `bounce-render` draws, `bounce-reference` measures). One module a
//! command, and a folder where a command has parts: `bake/` and `bench/`. Errors reach the user through `anyhow` with the library's message on top.

mod bake;
mod bench;
mod demo;
#[cfg(test)]
mod deploy_check;
mod indirect;
mod inspect;
mod lights_file;
mod memory;
mod progress;
mod reference_cmd;
mod relight_cmd;
mod render_cmd;
mod serve_cmd;
mod sky_cmd;
mod verify_cmd;
mod view;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "bounce",
    version,
    about = "Precomputed-radiosity lighting: bake glTF scenes into transport matrices",
    long_about = "bounce precomputes diffuse global illumination. `bake` turns a glTF scene into a \
                  baked file holding a multi-bounce light-transport matrix over voxel patches; \
                  `inspect` shows what a baked file holds; `relight` computes direct and indirect \
                  light per patch for light configurations; `demo` bakes the embedded Cornell box; \
                  `serve` streams per-patch light to viewers over gRPC."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Bake a glTF/GLB scene into a transport file, in one process or in shards (`--shard`,
    /// `bake transport`, `bake merge`).
    Bake(bake::BakeCommand),
    /// Show the header, layout, settings, timings and checks of a baked file.
    Inspect(inspect::InspectArgs),
    /// Bake the embedded Cornell box demo scene and inspect the result.
    Demo(demo::DemoArgs),
    /// Relight a baked scene: direct light with shadows and indirect light per patch for one
    /// batch of light configurations, on the GPU or the CPU.
    Relight(relight_cmd::RelightArgs),
    /// Draw one image of a glTF scene lit by a baked transport (direct light with shadow maps,
    /// indirect light from the irradiance volume), offscreen, to a PNG or linear EXR/PFM.
    Render(render_cmd::RenderArgs),
    /// Open a window on a glTF scene: direct light from its own shadow maps, indirect light
    /// streamed from a server session (or relit in process from a baked file); fly, move lights.
    View(view::ViewArgs),
    /// Benchmarks: tables (and CSV) comparing variants measured in one run.
    Bench(bench::BenchArgs),
    /// Path-trace indirect irradiance on the original triangles at the patches of a baked file
    /// (or at given points), with a standard error per value: the independent reference.
    Reference(reference_cmd::ReferenceArgs),
    /// Measure a baked file's indirect irradiance against the path-traced reference, split into
    /// codec error and method error.
    Verify(verify_cmd::VerifyArgs),
    /// A sky as a light file: an equirectangular HDR image (.hdr or .exr) as its order-2
    /// spherical harmonics, or a sun's direction as the sun and its clear sky (--sun).
    Sky(sky_cmd::SkyArgs),
    /// Serve baked scenes over gRPC: sessions, light changes, frames streamed to every viewer.
    /// With no --scenes, the embedded Cornell box demo.
    Serve(serve_cmd::ServeArgs),
}

/// Rust ignores SIGPIPE, so `bounce inspect x | head` would panic on the closed pipe; a command
/// line tool should instead end quietly, as `cat` does.
fn restore_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> ExitCode {
    restore_sigpipe();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bake(args) => bake::run(&args),
        Command::Inspect(args) => inspect::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Relight(args) => relight_cmd::run(&args),
        Command::Render(args) => render_cmd::run(&args),
        Command::View(args) => view::run(&args),
        Command::Bench(args) => bench::run(&args),
        Command::Serve(args) => serve_cmd::run(&args),
        Command::Reference(args) => reference_cmd::run(&args),
        Command::Verify(args) => verify_cmd::run(&args),
        Command::Sky(args) => sky_cmd::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
