//! `bounce bench codecs`: every codec on one exact transport, side by side, plus the thesis'
//! reordering table (none, one, two passes, from the bake's patch order and from a shuffled one)
//! and, on request, a sparse-share sweep; one table, one CSV, one SVG plot.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::codec::error::{entry_errors, irradiance_errors, probe_light_sets};
use bounce_core::codec::logblock::LogBlock;
use bounce_core::codec::transform::permute;
use bounce_core::codec::{self, Codec, MatrixOp};
use bounce_core::format::Baked;
use bounce_core::matrix::{DENSE_F32, DenseMatrix};
use clap::Args;

use super::plot::{Point, plot_codecs};
use super::table::emit;

#[derive(Args, Debug)]
pub struct BenchCodecsArgs {
    /// A file from `bounce bake` (its transport must be the exact dense-f32).
    pub baked: PathBuf,
    /// Light configurations in each product batch and in the error measurement.
    #[arg(long, default_value_t = 8)]
    pub batch: usize,
    /// Timed products per codec; the table shows the median.
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Also encode bc1 and bc1-resid at these sparse shares (comma separated), for the curves of
    /// error against bytes.
    #[arg(long, value_delimiter = ',', value_name = "S,S,...")]
    pub shares: Vec<f64>,
    /// Leave out the reordering table (six more bc1 encodes).
    #[arg(long)]
    pub no_reorder_table: bool,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
    /// Draw error against bytes and against product time as SVG here.
    #[arg(long, value_name = "OUT.svg")]
    pub plot: Option<PathBuf>,
}

/// One variant to measure: its label in the table, the series it belongs to in the plot, and
/// whether it runs on the shuffled matrix.
struct Variant {
    label: String,
    series: &'static str,
    codec: Box<dyn Codec>,
    shuffled: bool,
}

/// The exact matrix, its product operator and the probe light sets, in one patch order.
struct Reference {
    exact: DenseMatrix,
    op: Box<dyn MatrixOp>,
    b0: Vec<[f32; 3]>,
}

pub fn run(args: &BenchCodecsArgs) -> Result<()> {
    if args.batch == 0 || args.repeat == 0 {
        bail!("--batch and --repeat must be at least 1");
    }
    if let Some(s) = args.shares.iter().find(|s| !(0.0..=1.0).contains(*s)) {
        bail!("--shares must lie between 0 and 1, got {s}");
    }
    let baked =
        Baked::read(&args.baked).with_context(|| format!("reading {}", args.baked.display()))?;
    if baked.transport.codec != DENSE_F32 {
        bail!(
            "{} stores its transport as '{}'; the benchmark needs the exact dense-f32 to measure \
             against (bake with --codec dense-f32)",
            args.baked.display(),
            baked.transport.codec
        );
    }
    let exact = baked.transport.decode()?;
    let n = exact.n;
    let b0 = probe_light_sets(baked.transport_layout(), args.batch);
    eprintln!(
        "bench codecs: {} ({n} patches, {} channel(s)), batch {}, median of {}",
        args.baked.display(),
        exact.channels,
        args.batch,
        args.repeat
    );

    let variants = variants(args);
    let shuffled = variants
        .iter()
        .any(|v| v.shuffled)
        .then(|| shuffle(&exact, &b0));
    let reference = Reference {
        op: codec::decode(&baked.transport)?,
        exact,
        b0,
    };

    let header = [
        "codec",
        "bytes",
        "bytes_per_entry",
        "encode_s",
        "matvec_s",
        "entry_err_mean",
        "entry_err_max",
        "entry_err_sum",
        "eind_rel_l2",
        "eind_rel_max",
    ];
    let mut rows = Vec::new();
    let mut points = Vec::new();
    for v in &variants {
        let reference = match (&shuffled, v.shuffled) {
            (Some(s), true) => s,
            _ => &reference,
        };
        let start = Instant::now();
        let enc = v.codec.encode(&reference.exact)?;
        let encode_s = start.elapsed().as_secs_f64();
        let bytes = enc.payload.len() + enc.params.to_string().len();
        let op = codec::decode(&enc)?;
        let mut out = vec![[0.0f32; 3]; reference.b0.len()];
        let mut times = Vec::new();
        for _ in 0..args.repeat {
            let start = Instant::now();
            op.matvec_batch(&reference.b0, &mut out)?;
            times.push(start.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        let matvec_s = times[times.len() / 2];
        let entries = entry_errors(&reference.exact, &op.to_dense());
        let eind = irradiance_errors(reference.op.as_ref(), op.as_ref(), &reference.b0)?;
        eprintln!(
            "  {}: {bytes} bytes, E_ind rel L2 {:.2e}, encode {encode_s:.1} s",
            v.label, eind.rel_l2
        );
        rows.push(vec![
            v.label.clone(),
            bytes.to_string(),
            format!("{:.4}", bytes as f64 / (n * n).max(1) as f64),
            format!("{encode_s:.3}"),
            format!("{matvec_s:.5}"),
            format!("{:.3e}", entries.mean),
            format!("{:.3e}", entries.max),
            format!("{:.3e}", entries.sum),
            format!("{:.3e}", eind.rel_l2),
            format!("{:.3e}", eind.rel_max),
        ]);
        points.push(Point {
            label: v.label.clone(),
            series: v.series.to_string(),
            x: [bytes as f64, matvec_s],
            rel_l2: eind.rel_l2,
        });
    }
    emit(&header, &rows, args.csv.as_deref())?;
    if let Some(path) = &args.plot {
        let title = format!(
            "{} ({n} patches, {} channels): E_ind error of {} light sets",
            args.baked
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default(),
            reference.exact.channels,
            args.batch
        );
        plot_codecs(path, &title, &points)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn variants(args: &BenchCodecsArgs) -> Vec<Variant> {
    let mut out: Vec<Variant> = codec::all()
        .into_iter()
        .map(|c| Variant {
            label: c.name().to_string(),
            series: "codecs",
            codec: c,
            shuffled: false,
        })
        .collect();
    if !args.no_reorder_table {
        // The thesis' table: entry errors with no reordering, one pass, two passes. `bc1` above
        // is the two-pass row in the bake's patch order; the shuffled rows start from patches
        // numbered at random, as a scene whose export order says nothing about space would be.
        for (passes, shuffled) in [(0, false), (1, false), (0, true), (1, true), (2, true)] {
            let from = if shuffled { "shuffled-" } else { "" };
            out.push(Variant {
                label: format!("bc1-{from}reorder{passes}"),
                series: "reordering",
                codec: Box::new(LogBlock {
                    passes,
                    ..LogBlock::bc1()
                }),
                shuffled,
            });
        }
    }
    for &share in &args.shares {
        for (base, series) in [
            (LogBlock::bc1(), "bc1 by share"),
            (LogBlock::bc1_resid(), "bc1-resid by share"),
        ] {
            out.push(Variant {
                label: format!("{}@{share}", base.name),
                series,
                codec: Box::new(LogBlock {
                    sparse_share: share,
                    ..base
                }),
                shuffled: false,
            });
        }
    }
    out
}

/// The same transport with its patches numbered in a fixed pseudo-random order: `P T Pᵀ` and
/// the probe light sets gathered by `P`. Errors are invariant under the renumbering, so rows
/// measured on it compare directly with rows measured on the bake's order.
fn shuffle(exact: &DenseMatrix, b0: &[[f32; 3]]) -> Reference {
    let n = exact.n;
    let mut perm: Vec<u32> = (0..n as u32).collect();
    // Fisher–Yates with a fixed 64-bit LCG: deterministic, and good enough to destroy locality.
    let mut state = 0x853c_49e6_748f_ea9bu64;
    for i in (1..n).rev() {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let j = ((state >> 33) % (i as u64 + 1)) as usize;
        perm.swap(i, j);
    }
    let data = (0..exact.channels)
        .flat_map(|c| permute(exact.channel(c), n, &perm, &perm))
        .collect();
    let exact = DenseMatrix {
        n,
        channels: exact.channels,
        data,
    };
    let b0 = b0
        .chunks(n)
        .flat_map(|set| perm.iter().map(|&p| set[p as usize]))
        .collect();
    Reference {
        op: Box::new(codec::dense::DenseOp::from(exact.clone())),
        exact,
        b0,
    }
}
