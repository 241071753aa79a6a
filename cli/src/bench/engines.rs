//! `bounce bench engines`: every engine × codec × batch size on one baked scene, against the
//! exact solve, with the thesis' baselines (classic radiosity by Jacobi steps with `F`, the
//! precomputed dense `T`, the compressed `T`) measured in the same run.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bounce_core::codec::dense::DenseOp;
use bounce_core::codec::logblock::{self, LogBlock};
use bounce_core::codec::{self, Codec};
use bounce_core::direct::exitance_b0;
use bounce_core::format::Baked;
use bounce_core::light::{Light, LightSet};
use bounce_core::matrix::{DENSE_F32, DenseMatrix};
use bounce_core::meta::Bounces;
use bounce_core::patch::PatchLayout;
use bounce_engine::baseline::jacobi;
use bounce_engine::gpu::{BatchKernel, GpuContext, GpuMatrix, Split, bandwidth};
use bounce_engine::{Engine, EngineChoice};
use clap::Args;
use rayon::prelude::*;

use super::table::emit;

#[derive(Args, Debug)]
pub struct BenchEnginesArgs {
    /// A file from `bounce bake` with the exact dense-f32 transport (bake with
    /// --keep-form-factors to include the classic-radiosity baseline).
    pub baked: PathBuf,
    /// Codecs to run, comma separated (each encoded from the exact matrix in this run).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "dense-f32,dense-f16,bc1,bc1-resid"
    )]
    pub codecs: Vec<String>,
    /// Light sets per product, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "1,8,64")]
    pub batches: Vec<usize>,
    /// Timed products per row; the table shows the median and the p99.
    #[arg(long, default_value_t = 10)]
    pub repeat: usize,
    /// Seconds of untimed products before each row's timed ones (at least one product). A GPU
    /// that was idle, or busy with a bake, runs its first tens of milliseconds at low clocks:
    /// after a single warm-up product the same kernel measured up to 4 times slower on an H200
    /// (docs/h200, runs 7 and 8).
    #[arg(long, default_value_t = 0.5, value_name = "SECONDS")]
    pub warm_up: f64,
    /// Engines, comma separated: cpu, gpu. A GPU that cannot be opened is reported, not skipped
    /// silently.
    #[arg(long, value_delimiter = ',', default_value = "cpu,gpu")]
    pub engines: Vec<String>,
    /// Measure synthetic transports of these row counts instead of the file's own, comma
    /// separated: sizes a small machine cannot bake in reasonable time. Entry (i, j) is the
    /// file's T(i mod n, j mod n) · n / N, so rows keep their sums and the matrix its value and
    /// sparsity profile; the light is the file's B0 tiled the same way. The block codecs encode
    /// them without the reorder pass (its greedy chain is O(N³)), and past 8,192 rows with BC1's
    /// fast endpoint search, so their error is above what a bake of that size would give; the
    /// bytes a product reads are the same.
    #[arg(long, value_delimiter = ',', value_name = "N")]
    pub synthetic: Vec<usize>,
    /// GPU product kernels for batches over 8 light sets, comma separated, measured on the
    /// same upload: tiled (FP32, one pass per 64 sets, each entry decoded once a pass), tensor
    /// (the block codecs' tensor-core kernel, f16 inputs and f32 sums: the engine's choice
    /// where the device has one; elsewhere it is not measured and the bench says why) and
    /// matvec (the matrix-vector kernel, one pass per 8 sets). The table names them `gpu`,
    /// `gpu-tensor` and `gpu-matvec`.
    #[arg(long, value_delimiter = ',', default_value = "tiled,tensor")]
    pub kernels: Vec<Kernel>,
    /// Which columns the GPU's matrix-vector kernels (batches of up to 8 light sets) walk,
    /// comma separated, measured on the same upload: lit (the engine's default: only the
    /// groups of 64 columns some light set of the batch lights) and all (every column, the
    /// whole matrix read). The table names them `gpu` and `gpu-all-columns`; its `walked`
    /// column is the share of the matrix a GPU product read (`-` on the CPU, counted whole),
    /// and the bandwidth columns count those bytes only. The choices are timed in turns, each round in another order.
    #[arg(long, value_delimiter = ',', default_value = "lit")]
    pub columns: Vec<Columns>,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
}

#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Columns {
    Lit,
    All,
}

#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernel {
    Tiled,
    Tensor,
    Matvec,
}

/// One timed configuration.
struct Row {
    engine: String,
    codec: String,
    /// Rows (and columns) of the matrix.
    rows: usize,
    batch: usize,
    times: Vec<f64>,
    /// The device's own time for each timed product (GPU timestamp queries); empty where
    /// there is none.
    kernel_times: Vec<f64>,
    /// Bytes one pass over the whole matrix reads, passes per product, and the share of the
    /// matrix a GPU pass walked (below 1 where dark column groups were skipped). `None` where
    /// it is not measured: the CPU's products, which gather lit columns by their own rule
    /// (`bounce_core::codec::lanes`), are counted as reading the whole matrix.
    bytes: usize,
    passes: usize,
    walked: Option<f64>,
    rel_l2: f64,
    rel_max: f64,
}

/// Where a product runs: the CPU codec's operator, or the GPU kernels (with the device's own
/// memory bandwidth, measured in this run).
enum Device {
    Cpu,
    Gpu(Box<GpuContext>, f64),
}

enum Product {
    Cpu(Box<dyn codec::MatrixOp>),
    Gpu(Box<GpuMatrix>),
}

impl Product {
    fn apply(&self, x: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        match self {
            Product::Cpu(op) => op.matvec_batch(x, out)?,
            Product::Gpu(m) => m.matvec_batch(x, out)?,
        }
        Ok(())
    }

    /// Device time of the last product, where the device measures it.
    fn kernel_seconds(&self) -> Option<f64> {
        match self {
            Product::Cpu(_) => None,
            Product::Gpu(m) => m.last_kernel_seconds(),
        }
    }

    /// The share of the matrix the last GPU product's passes read (1 for the tiled and tensor
    /// kernels); `None` on the CPU.
    fn walked(&self) -> Option<f64> {
        match self {
            Product::Cpu(_) => None,
            Product::Gpu(m) => Some(m.last_lit_share().unwrap_or(1.0)),
        }
    }

    /// Whether the GPU's matrix-vector kernels skip dark column groups (CPU: no effect).
    fn set_columns(&mut self, columns: Columns) {
        if let Product::Gpu(m) = self {
            m.set_gather(columns == Columns::Lit);
        }
    }

    fn passes_for(&self, sets: usize) -> usize {
        match self {
            Product::Cpu(_) => usize::from(sets > 0),
            Product::Gpu(m) => m.passes(sets),
        }
    }

    /// The GPU kernels to measure this product with, and the engine name each row takes.
    fn kernels(&self, name: &str, wanted: &[Kernel]) -> Vec<(Kernel, String)> {
        match self {
            Product::Cpu(_) => vec![(Kernel::Tiled, name.to_string())],
            Product::Gpu(_) => wanted
                .iter()
                .map(|&k| match k {
                    Kernel::Tiled => (k, name.to_string()),
                    Kernel::Tensor => (k, format!("{name}-tensor")),
                    Kernel::Matvec => (k, format!("{name}-matvec")),
                })
                .collect(),
        }
    }

    /// Selects `kernel`; false where it cannot run on this product (a GPU product asked for
    /// tensor cores it has not got), which the caller reports instead of measuring.
    fn set_kernel(&mut self, kernel: Kernel) -> bool {
        let Product::Gpu(m) = self else { return true };
        let want = match kernel {
            Kernel::Tiled => BatchKernel::Tiled,
            Kernel::Tensor => BatchKernel::Tensor,
            Kernel::Matvec => BatchKernel::Matvec,
        };
        m.set_kernel(want) == want
    }

    /// Why the tensor kernel does not run on this product.
    fn no_tensor(&self) -> String {
        match self {
            Product::Gpu(m) => match m.tensor_refused() {
                Some(why) => format!("the driver refused it: {why}"),
                None => "the device has no tensor cores usable from WGSL, or the codec is \
                         not a block codec"
                    .to_string(),
            },
            Product::Cpu(_) => "CPU product".to_string(),
        }
    }
}

/// A matrix to measure: the file's exact transport, or a synthetic one tiled from it, with its
/// batch of `B0` and the exact product of that batch.
struct Subject {
    label: String,
    exact: DenseMatrix,
    b0: Vec<[f32; 3]>,
    reference: Vec<[f32; 3]>,
    /// Block codecs run their reorder pass (a real bake does; synthetic sizes skip it).
    reorder: bool,
}

pub fn run(args: &BenchEnginesArgs) -> Result<()> {
    if args.repeat == 0 || args.batches.contains(&0) || args.synthetic.contains(&0) {
        bail!("--repeat and every --batches and --synthetic entry must be at least 1");
    }
    if !(args.warm_up.is_finite() && args.warm_up >= 0.0) {
        bail!("--warm-up must be a number of seconds, 0 or more");
    }
    if let Some(&big) = args.synthetic.iter().find(|&&n| n > MAX_SYNTHETIC) {
        bail!("--synthetic {big}: at most {MAX_SYNTHETIC} rows (an n² entry index must fit u32)");
    }
    let baked =
        Baked::read(&args.baked).with_context(|| format!("reading {}", args.baked.display()))?;
    if baked.transport.codec != DENSE_F32 {
        bail!(
            "{} stores '{}'; the benchmark needs the exact dense-f32 transport to measure against \
             (bake with --codec dense-f32)",
            args.baked.display(),
            baked.transport.codec
        );
    }
    let exact = baked.transport.decode()?;
    let max_batch = args.batches.iter().copied().max().unwrap_or(1);

    // Light sets and their B0 on the transport's rows, once: direct light is the same CPU code
    // for every engine.
    let cpu = Engine::new(EngineChoice::Cpu)?;
    let cpu_scene = cpu.load(&baked)?;
    let n = cpu_scene.rows().len();
    let sets = bench_lights(&baked.layout, max_batch);
    let start = Instant::now();
    let direct = cpu.direct_on_rows(&cpu_scene, &sets)?;
    let direct_per_set = start.elapsed().as_secs_f64() / sets.len() as f64;
    let b0: Vec<[f32; 3]> = direct
        .iter()
        .flat_map(|d| exitance_b0(cpu_scene.rows(), d))
        .collect();
    let dark = b0.iter().filter(|v| **v == [0.0; 3]).count() as f64 / b0.len().max(1) as f64;
    let bandwidth = memory_bandwidth();
    eprintln!(
        "bench engines: {} ({} patches, {n} transport rows, {} channel(s)); direct light {:.1} ms \
         a light set (CPU, {} samples a row; {:.0}% of B0 entries dark); CPU memory bandwidth \
         {:.1} GB/s",
        args.baked.display(),
        baked.layout.len(),
        exact.channels,
        direct_per_set * 1e3,
        cpu.samples_for(&cpu_scene),
        dark * 100.0,
        bandwidth / 1e9
    );

    let devices = open_devices(args)?;
    let mut rows: Vec<Row> = Vec::new();
    if args.synthetic.is_empty() {
        let reference = product(&exact, &b0)?;
        let subject = Subject {
            label: args.baked.display().to_string(),
            exact,
            b0,
            reference,
            reorder: true,
        };
        rows.extend(direct_rows_all(args, &baked, &sets)?);
        rows.extend(probe_rows(args, &baked, &sets)?);
        rows.extend(product_rows(args, &devices, &subject)?);
        rows.extend(jacobi_rows(args, &baked, &subject.b0, &subject.reference)?);
    } else {
        for &size in &args.synthetic {
            let start = Instant::now();
            let exact = tile(&exact, size);
            let b0 = tile_lights(&b0, n, size, max_batch);
            let reference = product(&exact, &b0)?;
            eprintln!(
                "  synthetic {size}: {:.1} GB exact, tiled from {n} rows and multiplied in {:.1} s",
                exact.bytes() as f64 / 1e9,
                start.elapsed().as_secs_f64()
            );
            let subject = Subject {
                label: format!("synthetic {size}"),
                exact,
                b0,
                reference,
                reorder: false,
            };
            rows.extend(product_rows(args, &devices, &subject)?);
        }
    }

    let header = [
        "engine",
        "codec",
        "rows",
        "batch",
        "latency_ms_p50",
        "latency_ms_p99",
        "kernel_ms_p50",
        "lightsets_per_s",
        "matrix_mb",
        "passes",
        "walked",
        "effective_gb_per_s",
        "kernel_gb_per_s",
        "of_device_bandwidth",
        "eind_rel_l2",
        "eind_rel_max",
    ];
    let gpu_bandwidth = devices.iter().find_map(|(_, d)| match d {
        Device::Gpu(_, bw) => Some(*bw),
        Device::Cpu => None,
    });
    let table: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            let (p50, p99) = percentiles(&r.times);
            let read = (r.bytes * r.passes) as f64 * r.walked.unwrap_or(1.0);
            let gbs = read / p50;
            let kernel = (!r.kernel_times.is_empty()).then(|| percentiles(&r.kernel_times).0);
            // A GPU's share of its bandwidth is the kernels' own rate (the wall time also holds
            // the light's upload and the readback); a CPU's is the wall rate.
            let (device_bw, rate) = if r.engine.starts_with("gpu") {
                (gpu_bandwidth, kernel.map(|k| read / k))
            } else {
                (Some(bandwidth), Some(gbs))
            };
            vec![
                r.engine.clone(),
                r.codec.clone(),
                r.rows.to_string(),
                r.batch.to_string(),
                format!("{:.3}", p50 * 1e3),
                format!("{:.3}", p99 * 1e3),
                kernel.map_or("-".to_string(), |k| format!("{:.3}", k * 1e3)),
                format!("{:.1}", r.batch as f64 / p50),
                format!("{:.1}", r.bytes as f64 / 1e6),
                r.passes.to_string(),
                r.walked.map_or("-".to_string(), |w| format!("{w:.3}")),
                if r.bytes > 0 {
                    format!("{:.2}", gbs / 1e9)
                } else {
                    "-".to_string()
                },
                match kernel {
                    Some(k) if r.bytes > 0 => format!("{:.2}", read / k / 1e9),
                    _ => "-".to_string(),
                },
                match (device_bw, rate) {
                    (Some(bw), Some(rate)) if r.bytes > 0 => format!("{:.2}", rate / bw),
                    _ => "-".to_string(),
                },
                format!("{:.3e}", r.rel_l2),
                format!("{:.3e}", r.rel_max),
            ]
        })
        .collect();
    emit(&header, &table, args.csv.as_deref())
}

/// Runs `f` once, then again until `seconds` have passed since the first began.
fn warm_up(seconds: f64, mut f: impl FnMut() -> Result<()>) -> Result<()> {
    let start = Instant::now();
    f()?;
    while start.elapsed().as_secs_f64() < seconds {
        f()?;
    }
    Ok(())
}

/// Entries of an n × n matrix are indexed in u32 by the codecs' sparse parts.
const MAX_SYNTHETIC: usize = 65_535;

/// The engines to measure, each opened once; a GPU that cannot be opened is reported.
fn open_devices(args: &BenchEnginesArgs) -> Result<Vec<(String, Device)>> {
    let mut devices = Vec::new();
    for name in &args.engines {
        match name.parse::<EngineChoice>()? {
            EngineChoice::Auto => {
                bail!("--engines takes cpu and gpu; auto would measure one of them twice")
            }
            EngineChoice::Cpu => {
                eprintln!("  cpu: {} threads", rayon::current_num_threads());
                devices.push((name.clone(), Device::Cpu));
            }
            EngineChoice::Gpu => match GpuContext::new() {
                Ok(ctx) => {
                    let split = Split::of(ctx.device());
                    // 1 GiB (or the binding limit) read 10 times a submission.
                    let bw = bandwidth::measure(&ctx, 1 << 30, 10)?;
                    eprintln!(
                        "  gpu: {}; one binding {:.0} MiB, texture side {}, {} layers; memory \
                         read {:.1} GB/s ({:.0} MiB probe)",
                        ctx.adapter(),
                        split.binding_bytes as f64 / f64::from(1 << 20),
                        split.texture_side,
                        split.texture_layers,
                        bw.bytes_per_s / 1e9,
                        bw.bytes as f64 / f64::from(1 << 20)
                    );
                    devices.push((name.clone(), Device::Gpu(Box::new(ctx), bw.bytes_per_s)));
                }
                Err(e) => eprintln!("  {name}: not measured: {e}"),
            },
        }
    }
    Ok(devices)
}

/// Every codec × device × batch on one matrix.
fn product_rows(
    args: &BenchEnginesArgs,
    devices: &[(String, Device)],
    subject: &Subject,
) -> Result<Vec<Row>> {
    let n = subject.exact.n;
    let mut rows = Vec::new();
    for codec_name in &args.codecs {
        let codec = if subject.reorder {
            codec::configured(codec_name, None)?
        } else {
            without_reorder(codec_name, n)?
        };
        let encoded = encode(codec.as_ref(), &subject.exact)?;
        for (name, device) in devices {
            let loaded = match device {
                Device::Cpu => codec::decode(&encoded)
                    .map(Product::Cpu)
                    .map_err(Into::into),
                Device::Gpu(ctx, _) => GpuMatrix::upload(ctx, &encoded).map(|m| {
                    if m.pieces() > 1 {
                        eprintln!("    {codec_name}: {} pieces on the GPU", m.pieces());
                    }
                    Product::Gpu(Box::new(m))
                }),
            };
            let mut product: Product = match loaded {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("    {codec_name}: not measured on {name}: {e}");
                    continue;
                }
            };
            // Up to CHUNK sets every kernel choice runs the matrix-vector kernel: measured once,
            // under the first choice that runs.
            let mut small_measured = false;
            for (kernel, engine) in product.kernels(name, &args.kernels) {
                if !product.set_kernel(kernel) {
                    eprintln!(
                        "    {codec_name}: {engine} not measured: {}",
                        product.no_tensor()
                    );
                    continue;
                }
                let small_here = !small_measured;
                small_measured = true;
                for &batch in &args.batches {
                    let small = batch <= bounce_engine::gpu::CHUNK as usize;
                    if !small_here && small {
                        continue;
                    }
                    // Column choices apply to the matrix-vector kernels only, and the CPU has
                    // its own rule (lanes gather below half lit).
                    let choices: &[Columns] = match (&product, small) {
                        (Product::Gpu(_), true) => &args.columns,
                        _ => &[Columns::Lit],
                    };
                    // The choices are timed interleaved, each round in another order, so a
                    // GPU's clocks still rising (or a neighbour's load) weigh on every choice
                    // alike rather than on whichever ran first.
                    let x = &subject.b0[..batch * n];
                    let mut out = vec![[0.0f32; 3]; x.len()];
                    for &columns in choices {
                        product.set_columns(columns);
                        warm_up(args.warm_up, || product.apply(x, &mut out))?;
                    }
                    let mut times = vec![Vec::with_capacity(args.repeat); choices.len()];
                    let mut kernel_times = vec![Vec::with_capacity(args.repeat); choices.len()];
                    let mut walked = vec![None; choices.len()];
                    let mut errs = vec![(0.0, 0.0); choices.len()];
                    for round in 0..args.repeat {
                        for k in 0..choices.len() {
                            let c = (round + k) % choices.len();
                            product.set_columns(choices[c]);
                            let start = Instant::now();
                            product.apply(x, &mut out)?;
                            times[c].push(start.elapsed().as_secs_f64());
                            kernel_times[c].extend(product.kernel_seconds());
                            walked[c] = product.walked();
                            if round + 1 == args.repeat {
                                errs[c] = errors(&out, &subject.reference[..x.len()]);
                            }
                        }
                    }
                    for (c, &columns) in choices.iter().enumerate() {
                        let engine = match columns {
                            Columns::All if matches!(product, Product::Gpu(_)) => {
                                format!("{engine}-all-columns")
                            }
                            _ => engine.clone(),
                        };
                        let (rel_l2, rel_max) = errs[c];
                        rows.push(Row {
                            engine,
                            codec: codec_name.clone(),
                            rows: n,
                            batch,
                            times: std::mem::take(&mut times[c]),
                            kernel_times: std::mem::take(&mut kernel_times[c]),
                            bytes: encoded.payload.len(),
                            passes: product.passes_for(batch),
                            walked: walked[c],
                            rel_l2,
                            rel_max,
                        });
                        report(&subject.label, rows.last());
                    }
                    product.set_columns(Columns::Lit);
                }
            }
        }
    }
    Ok(rows)
}

/// A block codec as configured, but without the reorder pass, and past [`RANGE_FIT_FROM`] rows
/// with BC1's fast endpoint search (a product reads the same bytes; the bake's search costs
/// about 276 s at 32,768 rows on 16 cores, the fast one a tenth, with two to three times the
/// error); other codecs as they are.
fn without_reorder(name: &str, size: usize) -> Result<Box<dyn Codec>> {
    let base = match name {
        logblock::BC1 => LogBlock::bc1(),
        logblock::BC4 => LogBlock::bc4(),
        logblock::LOG8 => LogBlock::log8(),
        logblock::BC1_RESID => LogBlock::bc1_resid(),
        other => return Ok(codec::configured(other, None)?),
    };
    let fit = if size > RANGE_FIT_FROM {
        bounce_core::codec::bc::Fit::Range
    } else {
        bounce_core::codec::bc::Fit::Cluster
    };
    Ok(Box::new(LogBlock {
        passes: 0,
        fit,
        ..base
    }))
}

/// Synthetic sizes above this many rows encode BC1 with the fast endpoint search.
const RANGE_FIT_FROM: usize = 8192;

/// The exact product of a batch, on the CPU.
fn product(exact: &DenseMatrix, b0: &[[f32; 3]]) -> Result<Vec<[f32; 3]>> {
    let op = DenseOp::from(exact.clone());
    let mut out = vec![[0.0f32; 3]; b0.len()];
    codec::MatrixOp::matvec_batch(&op, b0, &mut out)?;
    Ok(out)
}

/// `T_N(i, j) = T(i mod n, j mod n) · n / N`.
fn tile(exact: &DenseMatrix, size: usize) -> DenseMatrix {
    let n = exact.n;
    let scale = n as f32 / size as f32;
    let mut m = DenseMatrix::zeros(size, exact.channels);
    for c in 0..exact.channels {
        let src = exact.channel(c);
        m.channel_mut(c)
            .par_chunks_mut(size)
            .enumerate()
            .for_each(|(i, row)| {
                let from = &src[(i % n) * n..(i % n + 1) * n];
                for (j, v) in row.iter_mut().enumerate() {
                    *v = from[j % n] * scale;
                }
            });
    }
    m
}

/// `sets` light vectors of `size` rows from ones of `n` rows, each tiled.
fn tile_lights(b0: &[[f32; 3]], n: usize, size: usize, sets: usize) -> Vec<[f32; 3]> {
    (0..sets)
        .flat_map(|k| (0..size).map(move |i| b0[k * n + i % n]))
        .collect()
}

/// What probes add to a relight (issue 22): the sparse gather `G · (B0 + ρ ⊙ E_ind)` of every
/// light set of the batch, on the host after the product (both engines run it there), timed on
/// the rows' own `B0` and `E_ind` and checked against the relight's probes. Nothing for a file
/// without probes.
fn probe_rows(args: &BenchEnginesArgs, baked: &Baked, sets: &[LightSet]) -> Result<Vec<Row>> {
    let Some(probes) = &baked.probes else {
        return Ok(Vec::new());
    };
    let cpu = Engine::new(EngineChoice::Cpu)?;
    let scene = cpu.load(baked)?;
    let n = baked.transport_layout().len();
    let label = format!(
        "probe gather ({} probes · {} entries)",
        probes.len(),
        probes.nnz()
    );
    let mut rows = Vec::new();
    for &batch in &args.batches {
        let sets = &sets[..batch];
        let (direct, near) = cpu.direct_and_near(&scene, sets)?;
        let mut b0 = Vec::with_capacity(batch * n);
        for (set, d) in sets.iter().zip(&direct) {
            b0.extend(scene.exitance(set, d)?);
        }
        // As a relight finishes `E_ind`: with the near field, where there is one.
        let ind = cpu.indirect_with_near(&scene, &b0, near.as_deref())?;
        let gather = || -> Vec<[f32; 3]> {
            sets.iter()
                .zip(b0.chunks(n).zip(ind.chunks(n)))
                .flat_map(|(set, (b, e))| scene.probe_irradiance(b, e, set))
                .collect()
        };
        warm_up(args.warm_up, || {
            std::hint::black_box(gather());
            Ok(())
        })?;
        let mut times = Vec::with_capacity(args.repeat);
        let mut got = Vec::new();
        for _ in 0..args.repeat {
            let start = Instant::now();
            got = std::hint::black_box(gather());
            times.push(start.elapsed().as_secs_f64());
        }
        // The relight's own probes: the gather measured is the one a relight runs.
        let want: Vec<[f32; 3]> = cpu
            .relight(&scene, sets)?
            .into_iter()
            .flat_map(|l| l.probes)
            .collect();
        let (rel_l2, rel_max) = errors(&got, &want);
        rows.push(Row {
            engine: "host".to_string(),
            codec: label.clone(),
            rows: n,
            batch,
            times,
            kernel_times: Vec::new(),
            // Per entry a row index and a share, read once a light set.
            bytes: probes.nnz() * 8,
            passes: batch,
            walked: None,
            rel_l2,
            rel_max,
        });
        report("probe gather", rows.last());
    }
    Ok(rows)
}

/// Direct light rows for every engine, on the file's own scene.
fn direct_rows_all(args: &BenchEnginesArgs, baked: &Baked, sets: &[LightSet]) -> Result<Vec<Row>> {
    let cpu = Engine::new(EngineChoice::Cpu)?;
    let cpu_scene = cpu.load(baked)?;
    let variants = light_variants(baked, sets);
    let references = variants
        .iter()
        .map(|(_, sets)| cpu.relight(&cpu_scene, sets))
        .collect::<Result<Vec<_>, _>>()?;
    let mut rows = Vec::new();
    for name in &args.engines {
        let engine = match Engine::new(name.parse()?) {
            Ok(e) => e,
            Err(e) => {
                eprintln!("  {name}: direct light not measured: {e}");
                continue;
            }
        };
        let scene = engine.load(baked)?;
        for ((suffix, sets), reference) in variants.iter().zip(&references) {
            rows.extend(direct_rows(args, &engine, &scene, sets, reference, suffix)?);
        }
        // The CPU's shadow rays with no answers kept between light sets, on the same light
        // sets in the same run: what the kept answers spare where a light stays put, and that
        // they change no value (the row's error against the reference is 0).
        if engine.direct_engine(&scene) == bounce_engine::EngineKind::Cpu
            && scene.shadow_source() == bounce_core::direct::ShadowSource::Triangles
        {
            let mut traced = engine.load(baked)?;
            traced.trace_every_shadow_ray();
            rows.extend(direct_rows(
                args,
                &engine,
                &traced,
                sets,
                &references[0],
                ", every ray traced",
            )?);
        }
    }
    Ok(rows)
}

/// The bench's light sets as they are, and, where the file can take them, with what a sky and
/// the scene's emissive surfaces add on the host (issue 22): each set with a uniform sky (a file
/// with a sky view), and each with every emissive material at half its strength (a file with
/// emitters). Their rows are labelled `+ sky` and `+ emissive`, measured in the same run.
fn light_variants(baked: &Baked, sets: &[LightSet]) -> Vec<(&'static str, Vec<LightSet>)> {
    let with = |extra: &[Light]| -> Vec<LightSet> {
        sets.iter()
            .map(|s| {
                let mut s = s.clone();
                s.lights.extend_from_slice(extra);
                s
            })
            .collect()
    };
    let mut out = vec![("", sets.to_vec())];
    if baked.sky.is_some() {
        let sky = Light::Sky {
            color: Some([0.5, 0.6, 0.8]),
            sh: None,
            name: None,
        };
        out.push((" + sky", with(&[sky])));
    }
    if let Some(e) = baked.emitters.as_ref().filter(|e| !e.groups.is_empty()) {
        let changes: Vec<Light> = bounce_core::emitter::materials_of(&e.names())
            .into_iter()
            .map(|material| {
                let strength = e
                    .groups
                    .iter()
                    .find(|g| g.name == material)
                    .map_or(1.0, |g| g.strength);
                Light::Emissive {
                    material: Some(material),
                    node: None,
                    color: None,
                    strength: Some(0.5 * strength),
                    name: None,
                }
            })
            .take(bounce_core::light::MAX_LIGHTS - 1)
            .collect();
        out.push((" + emissive", with(&changes)));
    }
    out
}

fn encode(
    codec: &dyn Codec,
    exact: &bounce_core::matrix::DenseMatrix,
) -> Result<bounce_core::matrix::EncodedMatrix> {
    let start = Instant::now();
    let enc = codec.encode(exact)?;
    eprintln!(
        "    encoded {} in {:.1} s",
        codec.name(),
        start.elapsed().as_secs_f64()
    );
    Ok(enc)
}

fn report(label: &str, row: Option<&Row>) {
    if let Some(r) = row {
        let (p50, _) = percentiles(&r.times);
        eprintln!(
            "    {label}, {} {} batch {}: {:.2} ms, E_ind rel L2 {:.2e}",
            r.engine,
            r.codec,
            r.batch,
            p50 * 1e3,
            r.rel_l2
        );
    }
}

/// Direct light with shadows for the first `batch` light sets, on the engine's own device (the
/// GPU kernel, or the CPU rays), against the CPU result.
fn direct_rows(
    args: &BenchEnginesArgs,
    engine: &Engine,
    scene: &bounce_engine::Scene,
    sets: &[LightSet],
    reference: &[bounce_engine::Irradiance],
    suffix: &str,
) -> Result<Vec<Row>> {
    let label = format!("direct light ({}){suffix}", engine.direct_engine(scene));
    let mut rows = Vec::new();
    for &batch in &args.batches {
        let sets = &sets[..batch];
        warm_up(args.warm_up, || {
            engine.relight_timed(scene, sets)?;
            Ok(())
        })?;
        let (mut lit, _) = engine.relight_timed(scene, sets)?;
        let mut times = Vec::with_capacity(args.repeat);
        for _ in 0..args.repeat {
            let (l, timing) = engine.relight_timed(scene, sets)?;
            times.push(timing.direct_s);
            lit = l;
        }
        let got: Vec<[f32; 3]> = lit.iter().flat_map(|l| l.direct.clone()).collect();
        let want: Vec<[f32; 3]> = reference[..batch]
            .iter()
            .flat_map(|l| l.direct.clone())
            .collect();
        let (rel_l2, rel_max) = errors(&got, &want);
        rows.push(Row {
            engine: engine.kind().to_string(),
            codec: label.clone(),
            rows: scene.layout.len(),
            batch,
            times,
            kernel_times: Vec::new(),
            bytes: 0,
            passes: 0,
            walked: None,
            rel_l2,
            rel_max,
        });
        report(&format!("direct light{suffix}"), rows.last());
    }
    Ok(rows)
}

/// Classic radiosity: `k` Jacobi products with the dense single-bounce `F`, where the file has
/// it and the bake used a fixed bounce count.
fn jacobi_rows(
    args: &BenchEnginesArgs,
    baked: &Baked,
    b0: &[[f32; 3]],
    reference: &[[f32; 3]],
) -> Result<Vec<Row>> {
    let layout = baked.transport_layout();
    let n = layout.len();
    let Some(ff) = &baked.form_factors else {
        eprintln!(
            "  jacobi-F: not measured: the file has no form factors (bake --keep-form-factors)"
        );
        return Ok(Vec::new());
    };
    let Bounces::K(k) = baked.meta.settings.bounces else {
        eprintln!("  jacobi-F: not measured: the bake is for all bounces, Jacobi would not stop");
        return Ok(Vec::new());
    };
    let f = codec::decode(ff)?;
    let mut rows = Vec::new();
    for &batch in &args.batches {
        let x = &b0[..batch * n];
        let mut out = jacobi(f.as_ref(), layout, x, k)?;
        let mut times = Vec::with_capacity(args.repeat);
        for _ in 0..args.repeat {
            let start = Instant::now();
            out = jacobi(f.as_ref(), layout, x, k)?;
            times.push(start.elapsed().as_secs_f64());
        }
        let (rel_l2, rel_max) = errors(&out, &reference[..x.len()]);
        rows.push(Row {
            engine: "cpu".to_string(),
            codec: format!("jacobi-F ({k} steps)"),
            rows: n,
            batch,
            times,
            kernel_times: Vec::new(),
            bytes: ff.payload.len(),
            passes: k as usize,
            walked: None,
            rel_l2,
            rel_max,
        });
        report("classic radiosity", rows.last());
    }
    Ok(rows)
}

/// Relative L2 over every value, and the worst patch (relative to the brightest patch's value,
/// so dark patches do not turn rounding into huge ratios).
fn errors(got: &[[f32; 3]], want: &[[f32; 3]]) -> (f64, f64) {
    let (mut num, mut den, mut worst, mut top) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (g, w) in got.iter().zip(want) {
        for c in 0..3 {
            let d = f64::from(g[c]) - f64::from(w[c]);
            num += d * d;
            den += f64::from(w[c]).powi(2);
            worst = worst.max(d.abs());
            top = top.max(f64::from(w[c]).abs());
        }
    }
    ((num / den.max(1e-300)).sqrt(), worst / top.max(1e-300))
}

fn percentiles(times: &[f64]) -> (f64, f64) {
    let mut t = times.to_vec();
    t.sort_by(f64::total_cmp);
    let at = |q: f64| t[((t.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99))
}

/// Light sets a viewer might send: alternately a point light a little off a surface somewhere in
/// the scene and a sun from a random direction above the horizon; deterministic.
fn bench_lights(layout: &PatchLayout, count: usize) -> Vec<LightSet> {
    let s = layout.voxel_size;
    let extent = layout
        .dims
        .iter()
        .map(|&d| d as f32 * s)
        .fold(0.0f32, f32::max);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..count)
        .map(|k| {
            let light = if k % 2 == 0 && !layout.is_empty() {
                let p = &layout.patches
                    [((next() * layout.len() as f32) as usize).min(layout.len() - 1)];
                let position = std::array::from_fn(|a| p.centroid[a] + p.normal[a] * 2.5 * s);
                Light::Point {
                    position,
                    color: [1.0, 0.9, 0.8],
                    // About 1 lux at a quarter of the scene away.
                    intensity: (extent * 0.25).powi(2),
                    range: None,
                    name: None,
                }
            } else {
                let (a, e) = (next() * std::f32::consts::TAU, 0.3 + 0.9 * next());
                Light::Directional {
                    direction: [a.cos() * e.cos(), -e.sin(), a.sin() * e.cos()],
                    color: [1.0, 0.97, 0.9],
                    intensity: 1.0,
                    name: None,
                }
            };
            LightSet {
                lights: vec![light],
            }
        })
        .collect()
}

/// Read bandwidth of this machine's memory: all threads summing a 256 MiB buffer, best of 5
/// (the figure products are compared with).
fn memory_bandwidth() -> f64 {
    let data = vec![1.0f32; 64 << 20];
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let start = Instant::now();
        let s: f32 = data
            .par_chunks(1 << 16)
            .map(|c| {
                let mut acc = [0.0f32; 8];
                for ch in c.chunks_exact(8) {
                    for l in 0..8 {
                        acc[l] += ch[l];
                    }
                }
                acc.iter().sum::<f32>()
            })
            .sum();
        std::hint::black_box(s);
        best = best.min(start.elapsed().as_secs_f64());
    }
    (data.len() * 4) as f64 / best
}
