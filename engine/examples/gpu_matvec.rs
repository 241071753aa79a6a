//! Times GPU batched products against the CPU twins on a synthetic matrix and prints a table.
//! A benchmark, not a test: `cargo run --release -p bounce-engine --example gpu_matvec [n]`.
//! On a software adapter (lavapipe) the numbers say nothing about GPUs; compare ratios only. The
//! CPU column means something only with `--release` (the dev profile leaves bounce-core at -O0).

use std::time::Instant;

use bounce_core::codec::{all, decode};
use bounce_core::matrix::DenseMatrix;
use bounce_engine::gpu::{GpuContext, GpuMatrix};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = match std::env::args().nth(1) {
        Some(a) => a.parse()?,
        None => 1024,
    };
    let ctx = GpuContext::new()?;
    println!("adapter: {}", ctx.adapter());
    let mut t = DenseMatrix::zeros(n, 3);
    let mut s = 1u64;
    for v in t.data.iter_mut() {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let u = (s >> 40) as f32 / (1u64 << 24) as f32;
        *v = if u < 0.2 {
            0.0
        } else {
            (u * 20.0 - 20.0).exp2() * 0.2
        };
    }
    println!("n = {n}, 3 channels");
    println!(
        "{:<10} {:>6} {:>7} {:>12} {:>12}",
        "codec", "batch", "passes", "gpu ms", "cpu ms"
    );
    for codec in all() {
        let enc = codec.encode(&t)?;
        let gpu = GpuMatrix::upload(&ctx, &enc)?;
        let cpu = decode(&enc)?;
        for sets in [1, 8, 64] {
            let x = vec![[1.0f32, 0.5, 0.25]; n * sets];
            let mut out = vec![[0.0f32; 3]; n * sets];
            gpu.matvec_batch(&x, &mut out)?; // warm-up: buffers, pipeline compilation
            let reps = 5;
            let t0 = Instant::now();
            for _ in 0..reps {
                gpu.matvec_batch(&x, &mut out)?;
            }
            let g = t0.elapsed().as_secs_f64() * 1e3 / f64::from(reps);
            let t0 = Instant::now();
            for _ in 0..reps {
                cpu.matvec_batch(&x, &mut out)?;
            }
            let c = t0.elapsed().as_secs_f64() * 1e3 / f64::from(reps);
            println!(
                "{:<10} {:>6} {:>7} {:>12.2} {:>12.2}",
                codec.name(),
                sets,
                GpuMatrix::passes_for(sets),
                g,
                c
            );
        }
    }
    Ok(())
}
