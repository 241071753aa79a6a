//! Tests of the exact bc1-codec building blocks: sparse split, log quantisation, greedy
//! reordering and permutations.

use bounce_core::codec::transform::*;
use proptest::prelude::*;

/// Small deterministic generator so the sweeps are reproducible without a rand dependency.
struct XorShift(u64);

impl XorShift {
    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn below(&mut self, k: usize) -> usize {
        (self.next_u64() % k as u64) as usize
    }
    fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i + 1);
            v.swap(i, j);
        }
    }
}

/// A transport-like channel: mostly small log-spread values, some exact zeros.
fn random_channel(rng: &mut XorShift, n: usize, zero_share: f64) -> Vec<f32> {
    (0..n * n)
        .map(|_| {
            if rng.unit() < zero_share {
                0.0
            } else {
                (10f64.powf(-8.0 * rng.unit())) as f32
            }
        })
        .collect()
}

/// The positions the split must take, computed the slow obvious way: sort all non-zero
/// positions by (largest channel descending, index ascending) and take the first `k`.
fn reference_positions(channels: &[Vec<f32>], n: usize, share: f64) -> Vec<usize> {
    let mut keyed: Vec<(f32, usize)> = (0..n * n)
        .map(|p| {
            let k = channels.iter().map(|c| c[p]).fold(0.0f32, f32::max);
            (k, p)
        })
        .filter(|(k, _)| *k > 0.0)
        .collect();
    keyed.sort_by(|a, b| b.0.partial_cmp(&a.0).unwrap().then(a.1.cmp(&b.1)));
    let k = (share * (n * n) as f64).round() as usize;
    let mut pos: Vec<usize> = keyed.into_iter().take(k).map(|(_, p)| p).collect();
    pos.sort_unstable();
    pos
}

/// Positions held by a SparsePart, as linear indices, in CSR order.
fn sparse_positions(sp: &SparsePart) -> Vec<usize> {
    let mut out = Vec::new();
    for i in 0..sp.n {
        for k in sp.row_ptr[i] as usize..sp.row_ptr[i + 1] as usize {
            out.push(i * sp.n + sp.col_idx[k] as usize);
        }
    }
    out
}

/// Checks every property of a split against the original channels.
fn check_split(original: &[Vec<f32>], n: usize, share: f64) {
    let mut dense = original.to_vec();
    let sp = split_largest(&mut dense, n, share);
    let expected = reference_positions(original, n, share);

    assert_eq!(sp.n, n);
    assert_eq!(sp.channels, original.len());
    assert_eq!(sp.row_ptr.len(), n + 1);
    assert_eq!(sp.nnz(), expected.len(), "wrong number of kept positions");
    assert_eq!(
        sparse_positions(&sp),
        expected,
        "kept positions are not the largest"
    );
    assert_eq!(sp.values.len(), sp.nnz() * original.len());
    for i in 0..n {
        let cols = &sp.col_idx[sp.row_ptr[i] as usize..sp.row_ptr[i + 1] as usize];
        assert!(
            cols.windows(2).all(|w| w[0] < w[1]),
            "columns not ascending"
        );
    }
    assert_eq!(
        sp.bytes(),
        4 * (n + 1) + 4 * sp.nnz() + 4 * sp.nnz() * original.len()
    );

    // Dense part zeroed at kept positions, untouched elsewhere; dense + sparse == original.
    let nnz = sp.nnz();
    for (c, ch) in original.iter().enumerate() {
        let mut rebuilt = dense[c].clone();
        for (k, &p) in expected.iter().enumerate() {
            assert_eq!(dense[c][p], 0.0, "kept position not zeroed");
            rebuilt[p] += sp.values[c * nnz + k];
        }
        for p in 0..n * n {
            if expected.binary_search(&p).is_err() {
                assert_eq!(
                    dense[c][p].to_bits(),
                    ch[p].to_bits(),
                    "untouched entry changed"
                );
            }
            assert_eq!(
                rebuilt[p].to_bits(),
                ch[p].to_bits(),
                "dense + sparse != original"
            );
        }
    }
}

#[test]
fn split_keeps_exactly_the_largest_share() {
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    for &(n, n_ch, share, zeros) in &[
        (50usize, 3usize, 0.04, 0.3),
        (50, 1, 0.04, 0.0),
        (7, 3, 0.04, 0.2), // 49 * 0.04 = 1.96 -> 2 positions
        (33, 3, 0.25, 0.5),
        (20, 1, 0.0, 0.1),
        (20, 3, 1.0, 0.1),
    ] {
        let original: Vec<Vec<f32>> = (0..n_ch)
            .map(|_| random_channel(&mut rng, n, zeros))
            .collect();
        check_split(&original, n, share);
    }
}

#[test]
fn split_rounds_the_count() {
    let mut rng = XorShift(7);
    let n = 7;
    let original = vec![random_channel(&mut rng, n, 0.0)];
    let mut dense = original.clone();
    assert_eq!(split_largest(&mut dense, n, 0.04).nnz(), 2);
    let mut dense = original.clone();
    assert_eq!(split_largest(&mut dense, n, 0.03).nnz(), 1); // 1.47 -> 1
}

#[test]
fn split_breaks_ties_by_lower_index_and_ranks_by_largest_channel() {
    let n = 4;
    // Channel 0 all 1.0 except one position; channel 1 lifts position 9 above everything.
    let mut c0 = vec![1.0f32; n * n];
    let mut c1 = vec![0.0f32; n * n];
    c0[9] = 0.5;
    c1[9] = 2.0;
    let original = vec![c0, c1];
    // 3 positions: 9 (largest over channels), then ties at 1.0 go to indices 0 and 1.
    let mut dense = original.clone();
    let sp = split_largest(&mut dense, n, 3.0 / 16.0);
    assert_eq!(sparse_positions(&sp), vec![0, 1, 9]);
    // Both channels of position 9 moved, including the smaller one.
    assert_eq!(sp.values[2], 0.5);
    assert_eq!(sp.values[3 + 2], 2.0);
    check_split(&original, n, 3.0 / 16.0);
}

#[test]
fn split_never_takes_zero_entries() {
    let n = 10;
    let mut c = vec![0.0f32; n * n];
    for (k, p) in [3usize, 17, 42, 58, 99].into_iter().enumerate() {
        c[p] = (k + 1) as f32;
    }
    let original = vec![c];
    let mut dense = original.clone();
    let sp = split_largest(&mut dense, n, 0.5);
    assert_eq!(sparse_positions(&sp), vec![3, 17, 42, 58, 99]);
    assert!(dense[0].iter().all(|&v| v == 0.0));
    check_split(&original, n, 0.5);
}

#[test]
fn split_clamps_odd_shares() {
    let mut rng = XorShift(11);
    let original = vec![random_channel(&mut rng, 6, 0.0)];
    let mut d = original.clone();
    assert_eq!(split_largest(&mut d, 6, f64::NAN).nnz(), 0);
    let mut d = original.clone();
    assert_eq!(split_largest(&mut d, 6, -1.0).nnz(), 0);
    let mut d = original.clone();
    assert_eq!(split_largest(&mut d, 6, 7.0).nnz(), 36);
}

#[test]
fn matvec_add_equals_dense_matvec_of_sparse_entries() {
    let mut rng = XorShift(0xdead_beef);
    let n = 40;
    let original: Vec<Vec<f32>> = (0..3).map(|_| random_channel(&mut rng, n, 0.2)).collect();
    let mut dense = original.clone();
    let sp = split_largest(&mut dense, n, 0.1);
    assert!(sp.nnz() > 0);
    let x: Vec<f32> = (0..n).map(|_| rng.unit() as f32 - 0.3).collect();
    for c in 0..3 {
        // The sparse entries as a dense matrix: original minus what stayed dense.
        let s: Vec<f32> = original[c]
            .iter()
            .zip(&dense[c])
            .map(|(o, d)| o - d)
            .collect();
        let base: Vec<f32> = (0..n).map(|i| i as f32).collect();
        let mut out = base.clone();
        sp.matvec_add(c, &x, &mut out);
        for i in 0..n {
            let expected: f64 = (0..n)
                .map(|j| f64::from(s[i * n + j]) * f64::from(x[j]))
                .sum::<f64>()
                + f64::from(base[i]);
            let got = f64::from(out[i]);
            assert!(
                (got - expected).abs() <= 1e-6 * (1.0 + expected.abs()),
                "row {i} channel {c}: {got} vs {expected}"
            );
        }
    }
}

/// The exact (f64) code position of `x`, used to tell clamped values from rounded ones.
fn code_position(x: f32, max: f32) -> f64 {
    255.0 * ((f64::from(x) / f64::from(max)).ln() + 25.0) / 25.0
}

/// f32 result of the dequantiser carries a few ulps of its own on top of the exact bound.
const F32_SLACK: f32 = 1e-6;

fn check_log_roundtrip(values: &[f32]) {
    let (codes, max) = log_quantize(values);
    let true_max = values.iter().copied().fold(0.0f32, f32::max);
    assert_eq!(max, true_max);
    assert_eq!(codes.len(), values.len());
    for (&x, &q) in values.iter().zip(&codes) {
        if x == 0.0 {
            assert_eq!(q, 0, "zero must stay zero");
            assert_eq!(log_dequantize(q, max), 0.0);
            continue;
        }
        assert!(q >= 1, "positive {x} became zero");
        let t = code_position(x, max);
        if t >= 0.5 {
            let back = log_dequantize(q, max);
            let rel = (back - x).abs() / x;
            assert!(
                rel <= LOG_QUANT_REL_BOUND + F32_SLACK,
                "x {x} max {max} q {q} back {back} rel {rel}"
            );
        }
    }
    // Monotonic: sorting by value sorts the codes.
    let mut pairs: Vec<(f32, u8)> = values.iter().copied().zip(codes.iter().copied()).collect();
    pairs.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
    assert!(
        pairs.windows(2).all(|w| w[0].1 <= w[1].1),
        "codes not monotonic"
    );
}

#[test]
fn log_quantize_sweep_over_magnitudes() {
    let mut rng = XorShift(42);
    // Log-uniform 1e-12..1, with max exactly 1 and a few zeros.
    let mut values: Vec<f32> = (0..200_000)
        .map(|_| 10f64.powf(-12.0 * rng.unit()) as f32)
        .collect();
    values.push(1.0);
    values.extend([0.0; 10]);
    check_log_roundtrip(&values);
    // Same data at other scales: the max normalises it away.
    for scale in [1e-20f32, 1e-6, 3.7, 1e15] {
        let scaled: Vec<f32> = values.iter().map(|v| v * scale).collect();
        check_log_roundtrip(&scaled);
    }
    // The bound is attained closely somewhere, so a looser quantiser would fail.
    let (codes, max) = log_quantize(&values);
    let worst = values
        .iter()
        .zip(&codes)
        .filter(|(x, _)| **x > 0.0 && code_position(**x, max) >= 0.5)
        .map(|(&x, &q)| (log_dequantize(q, max) - x).abs() / x)
        .fold(0.0f32, f32::max);
    assert!(worst > 0.9 * LOG_QUANT_REL_BOUND, "worst {worst}");
}

#[test]
fn log_quantize_edges() {
    assert!((LOG_QUANT_REL_BOUND - ((25.0f64 / 510.0).exp() - 1.0) as f32).abs() < 1e-8);
    let (codes, max) = log_quantize(&[0.0, 0.0]);
    assert_eq!((codes, max), (vec![0, 0], 0.0));
    let (codes, max) = log_quantize(&[]);
    assert_eq!((codes.len(), max), (0, 0.0));
    // The maximum maps to 255 and back exactly.
    let (codes, max) = log_quantize(&[2.5, 0.0, 1e-30]);
    assert_eq!(codes, vec![255, 0, 1]);
    assert_eq!(log_dequantize(255, max), 2.5);
    // Far below the range: clamped to 1, not 0.
    assert_eq!(
        log_dequantize(1, max),
        (2.5f64 * (25.0f64 / 255.0 - 25.0).exp()) as f32
    );
    // Every code decodes to a distinct, increasing value.
    let decoded: Vec<f32> = (0..=255u8).map(|q| log_dequantize(q, 1.0)).collect();
    assert!(decoded.windows(2).all(|w| w[0] < w[1]));
}

proptest! {
    #[test]
    fn log_quantize_prop(values in prop::collection::vec(
        prop_oneof![Just(0.0f32), (-40.0f32..3.0).prop_map(|e| 10f32.powf(e))], 1..200)) {
        check_log_roundtrip(&values);
    }
}

/// Total SAD between consecutive rows in the order `perm`.
fn chain_sad(rows: &[u8], row_len: usize, perm: &[u32]) -> u64 {
    perm.windows(2)
        .map(|w| {
            let a = &rows[w[0] as usize * row_len..][..row_len];
            let b = &rows[w[1] as usize * row_len..][..row_len];
            a.iter()
                .zip(b)
                .map(|(&x, &y)| u64::from(x.abs_diff(y)))
                .sum::<u64>()
        })
        .sum()
}

/// The obvious serial greedy chain, the reference for the pruned parallel one.
fn naive_chain(rows: &[u8], n_rows: usize, row_len: usize) -> Vec<u32> {
    if n_rows == 0 {
        return Vec::new();
    }
    let mut visited = vec![false; n_rows];
    let mut perm = vec![0u32];
    visited[0] = true;
    for _ in 1..n_rows {
        let last = *perm.last().unwrap() as usize;
        let mut best = (u64::MAX, usize::MAX);
        for (cand, &v) in visited.iter().enumerate() {
            if v {
                continue;
            }
            let d = chain_sad(rows, row_len, &[last as u32, cand as u32]);
            if (d, cand) < best {
                best = (d, cand);
            }
        }
        visited[best.1] = true;
        perm.push(best.1 as u32);
    }
    perm
}

#[test]
fn greedy_chain_groups_duplicates() {
    let mut rng = XorShift(123);
    let (groups, copies, row_len) = (12usize, 5usize, 300usize);
    let bases: Vec<Vec<u8>> = (0..groups)
        .map(|_| (0..row_len).map(|_| rng.below(256) as u8).collect())
        .collect();
    let mut labels: Vec<usize> = (0..groups).flat_map(|g| vec![g; copies]).collect();
    rng.shuffle(&mut labels);
    let rows: Vec<u8> = labels.iter().flat_map(|&g| bases[g].clone()).collect();
    let n_rows = labels.len();

    let perm = greedy_chain(&rows, n_rows, row_len);
    assert!(is_permutation(&perm, n_rows));
    // Each group is one contiguous run, so the chain crosses groups exactly groups-1 times...
    let order: Vec<usize> = perm.iter().map(|&r| labels[r as usize]).collect();
    let switches = order.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(switches, groups - 1, "duplicates split apart: {order:?}");
    // ...and its total SAD is exactly that of the grouped order (all within-group steps cost 0).
    let mut group_seq: Vec<usize> = vec![order[0]];
    for &g in &order[1..] {
        if g != *group_seq.last().unwrap() {
            group_seq.push(g);
        }
    }
    let grouped: u64 = group_seq
        .windows(2)
        .map(|w| {
            bases[w[0]]
                .iter()
                .zip(&bases[w[1]])
                .map(|(&x, &y)| u64::from(x.abs_diff(y)))
                .sum::<u64>()
        })
        .sum();
    assert_eq!(chain_sad(&rows, row_len, &perm), grouped);
    assert_eq!(perm, naive_chain(&rows, n_rows, row_len));
}

#[test]
fn greedy_chain_reduces_sad_on_structured_matrix() {
    // Rows sampled from a smooth 1-D family (a bump moving across the row), then shuffled:
    // the identity order jumps around, a good chain walks the family.
    let mut rng = XorShift(99);
    let (n_rows, row_len) = (200usize, 256usize);
    let mut phases: Vec<f64> = (0..n_rows).map(|i| i as f64 / n_rows as f64).collect();
    rng.shuffle(&mut phases);
    let rows: Vec<u8> = phases
        .iter()
        .flat_map(|&ph| {
            (0..row_len).map(move |j| {
                let d = j as f64 / row_len as f64 - ph;
                (255.0 * (-d * d * 40.0).exp()).round() as u8
            })
        })
        .collect();
    let identity: Vec<u32> = (0..n_rows as u32).collect();
    let perm = greedy_chain(&rows, n_rows, row_len);
    assert!(is_permutation(&perm, n_rows));
    let before = chain_sad(&rows, row_len, &identity);
    let after = chain_sad(&rows, row_len, &perm);
    assert!(after * 4 < before, "chain SAD {after} vs identity {before}");
    assert_eq!(perm, naive_chain(&rows, n_rows, row_len));
}

#[test]
fn greedy_chain_small_cases() {
    assert!(greedy_chain(&[], 0, 5).is_empty());
    assert_eq!(greedy_chain(&[1, 2, 3], 1, 3), vec![0]);
    // Zero-length rows: all distances tie, so lower index wins each step.
    assert_eq!(greedy_chain(&[], 4, 0), vec![0, 1, 2, 3]);
    // Values 0,10,1,11,0: 0 -> 4 (equal) -> 2 (1 away) -> 1 (9 beats 10) -> 3.
    let rows = [0u8, 10, 1, 11, 0];
    assert_eq!(greedy_chain(&rows, 5, 1), vec![0, 4, 2, 1, 3]);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// A small alphabet forces many equal distances, which exercises pruning and tie-breaking.
    #[test]
    fn greedy_chain_matches_naive(
        n_rows in 1usize..40,
        row_len in 1usize..9000,
        alphabet in 1u8..4,
        seed in any::<u64>(),
    ) {
        let mut rng = XorShift(seed | 1);
        let rows: Vec<u8> = (0..n_rows * row_len)
            .map(|_| (rng.below(alphabet as usize + 1) as u8) * 60)
            .collect();
        let perm = greedy_chain(&rows, n_rows, row_len);
        prop_assert!(is_permutation(&perm, n_rows));
        prop_assert_eq!(perm, naive_chain(&rows, n_rows, row_len));
    }
}

#[test]
fn permutation_helpers() {
    let mut rng = XorShift(5);
    for n in [0usize, 1, 2, 17, 64] {
        let mut p: Vec<u32> = (0..n as u32).collect();
        rng.shuffle(&mut p);
        assert!(is_permutation(&p, n));
        let inv = invert(&p);
        assert!(is_permutation(&inv, n));
        for (k, &pk) in p.iter().enumerate() {
            assert_eq!(inv[pk as usize] as usize, k);
        }
        assert_eq!(invert(&inv), p);
    }
    assert!(!is_permutation(&[0, 1, 1], 3));
    assert!(!is_permutation(&[0, 1, 3], 3));
    assert!(!is_permutation(&[0, 1], 3));
    assert!(!is_permutation(&[0, 1, 2], 2));
}

#[test]
fn permute_matches_definition_and_inverts() {
    let mut rng = XorShift(77);
    let n = 23;
    let m: Vec<u8> = (0..n * n).map(|_| rng.below(256) as u8).collect();
    let mut rp: Vec<u32> = (0..n as u32).collect();
    let mut cp = rp.clone();
    rng.shuffle(&mut rp);
    rng.shuffle(&mut cp);
    let pm = permute(&m, n, &rp, &cp);
    for k in 0..n {
        for l in 0..n {
            assert_eq!(pm[k * n + l], m[rp[k] as usize * n + cp[l] as usize]);
        }
    }
    let back = permute(&pm, n, &invert(&rp), &invert(&cp));
    assert_eq!(back, m);
    // Row and column permutations act independently.
    let id: Vec<u32> = (0..n as u32).collect();
    assert_eq!(permute(&permute(&m, n, &rp, &id), n, &id, &cp), pm);
}

#[test]
#[should_panic(expected = "not a permutation")]
fn permute_rejects_non_permutation() {
    permute(&[1u8, 2, 3, 4], 2, &[0, 0], &[0, 1]);
}

#[test]
fn reordering_is_lossless_for_matvec() {
    let mut rng = XorShift(2024);
    let n = 31;
    let mut rp: Vec<u32> = (0..n as u32).collect();
    let mut cp = rp.clone();
    rng.shuffle(&mut rp);
    rng.shuffle(&mut cp);

    // Integers: exact arithmetic, so (P M Q)(Qᵀ x) must equal P (M x) bit for bit.
    let m: Vec<i64> = (0..n * n).map(|_| rng.below(1000) as i64 - 300).collect();
    let x: Vec<i64> = (0..n).map(|_| rng.below(100) as i64 - 50).collect();
    let matvec = |a: &[i64], v: &[i64]| -> Vec<i64> {
        (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * v[j]).sum())
            .collect()
    };
    let pmq = permute(&m, n, &rp, &cp);
    let qx: Vec<i64> = cp.iter().map(|&c| x[c as usize]).collect();
    let lhs = matvec(&pmq, &qx);
    let mx = matvec(&m, &x);
    let rhs: Vec<i64> = rp.iter().map(|&r| mx[r as usize]).collect();
    assert_eq!(lhs, rhs);

    // f32 (the real use): equal up to summation order.
    let mf: Vec<f32> = (0..n * n).map(|_| rng.unit() as f32).collect();
    let xf: Vec<f32> = (0..n).map(|_| rng.unit() as f32).collect();
    let pmqf = permute(&mf, n, &rp, &cp);
    for k in 0..n {
        let lhs: f32 = (0..n).map(|l| pmqf[k * n + l] * xf[cp[l] as usize]).sum();
        let r = rp[k] as usize;
        let rhs: f32 = (0..n).map(|j| mf[r * n + j] * xf[j]).sum();
        assert!(
            (lhs - rhs).abs() <= 1e-5 * rhs.abs(),
            "row {k}: {lhs} vs {rhs}"
        );
    }
}
