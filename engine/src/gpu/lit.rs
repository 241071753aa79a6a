//! Which column groups of a product are lit: the matrix-vector kernels walk only those.
//!
//! Most of a scene is dark under any one light (81% of the Cornell box's `B0` entries and 92–93%
//! of `pandora`'s under `bench engines`' lights), and a dark column contributes
//! nothing to `T · B0`. The CPU products gather the lit columns (`bounce_core::codec::lanes`);
//! this is the GPU's twin at the granularity its kernels read the matrix: groups of
//! [`LIT_GROUP`] consecutive storage columns, one column a thread.

use super::kernel::LIT_GROUP;

/// The ascending indices of the [`LIT_GROUP`]-column groups of storage columns `0..n` in which
/// some light set of `x` (`sets × n`, set `k` at `x[k·n..]`) is non-zero, storage column `l`
/// multiplying patch `order[l]` (patch `l` without an order). `None` when every group is lit:
/// the kernel then walks the columns without the list.
pub fn lit_groups(x: &[[f32; 3]], n: usize, order: Option<&[u32]>) -> Option<Vec<u32>> {
    if n == 0 {
        return None;
    }
    let sets = x.len() / n;
    let mut lit_patch = vec![false; n];
    for set in x.chunks_exact(n).take(sets) {
        for (lit, v) in lit_patch.iter_mut().zip(set) {
            *lit |= *v != [0.0; 3];
        }
    }
    let groups = n.div_ceil(LIT_GROUP);
    let patch = |l: usize| order.map_or(Some(l), |o| o.get(l).map(|&p| p as usize));
    let list: Vec<u32> = (0..groups)
        .filter(|&g| {
            (g * LIT_GROUP..((g + 1) * LIT_GROUP).min(n))
                .any(|l| patch(l).is_some_and(|p| lit_patch.get(p).copied().unwrap_or(false)))
        })
        .map(|g| g as u32)
        .collect();
    (list.len() < groups).then_some(list)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dark(n: usize) -> Vec<[f32; 3]> {
        vec![[0.0; 3]; n]
    }

    #[test]
    fn a_group_is_lit_when_any_set_lights_any_of_its_columns() {
        let n = 3 * LIT_GROUP + 5;
        let mut x = dark(2 * n);
        x[LIT_GROUP + 7] = [0.0, 0.5, 0.0]; // set 0, group 1
        x[n + 3 * LIT_GROUP + 4] = [1.0, 0.0, 0.0]; // set 1, the short last group
        assert_eq!(lit_groups(&x, n, None), Some(vec![1, 3]));
    }

    #[test]
    fn every_group_lit_walks_every_column() {
        let n = 2 * LIT_GROUP;
        let mut x = dark(n);
        x[0] = [1.0; 3];
        x[LIT_GROUP] = [1.0; 3];
        assert_eq!(lit_groups(&x, n, None), None);
    }

    #[test]
    fn all_dark_walks_nothing() {
        assert_eq!(lit_groups(&dark(100), 100, None), Some(vec![]));
    }

    #[test]
    fn the_column_order_decides_which_group_a_patch_falls_in() {
        let n = 2 * LIT_GROUP;
        // Storage column l holds patch n - 1 - l: patch 0 sits in the last group.
        let order: Vec<u32> = (0..n as u32).rev().collect();
        let mut x = dark(n);
        x[0] = [0.25; 3];
        assert_eq!(lit_groups(&x, n, Some(&order)), Some(vec![1]));
        assert_eq!(lit_groups(&x, n, None), Some(vec![0]));
    }
}
