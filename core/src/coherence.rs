//! Blockers remembered from the last light set: where a light moved a little, the triangle that
//! blocked a sample's shadow ray last time most likely blocks it again.
//!
//! This module owns one saving of the CPU's direct light ([`crate::direct`]) on a
//! surface-geometry scene, and like [`crate::visibility`] it never changes a value: a hint is
//! one triangle test before the shadow cache and the tree, and a ray no hint blocks is traced as
//! before. What the kept answers cannot do, this does: a light that moves every set (a torch
//! carried through a level, a sun across a day) traces every ray again, and without hints a
//! blocked ray the shadow cache's few triangles miss walks the tree, about 1 µs. With the last
//! set's blocker of the same sample towards the nearest light of the same kind, most of those
//! rays cost one triangle test.
//!
//! Kept for the last light set only: per row, per light, per sample one `u32` (the blocker's
//! index in the mesh, or [`NONE`]), 1.5 MB a light for `pandora`'s 11,810 rows at 32 samples,
//! within a budget ([`crate::visibility::DEFAULT_BUDGET`], shared with the kept answers' setting);
//! a set whose hints would not fit keeps none.

use std::sync::{Arc, Mutex};

use crate::visibility::{LightPlace, PlaceKey};

/// No blocker known: the ray was open, untraced, or never asked.
pub const NONE: u32 = u32::MAX;

/// One light set's blockers: per row `lights × per_row` ids, light after light.
#[derive(Debug)]
struct Blockers {
    places: Vec<LightPlace>,
    per_row: usize,
    rows: usize,
    ids: Vec<u32>,
}

impl Blockers {
    fn stride(&self) -> usize {
        stride(self.places.len(), self.per_row)
    }
}

/// u32 a row takes (at least 1, so rows can be taken as chunks when no light is kept).
fn stride(lights: usize, per_row: usize) -> usize {
    (lights * per_row).max(1)
}

/// The last light set's blockers of a scene, and the budget they must fit.
#[derive(Debug)]
pub struct BlockerMemory {
    budget: usize,
    last: Mutex<Option<Arc<Blockers>>>,
    /// The ids of the set before the last, for the next set to write over: no allocation
    /// (and no page faults) a set.
    spare: Mutex<Vec<u32>>,
}

/// What one light set reads: the last set's blockers (if any fit and match) and which of its
/// lights each new light takes hints from; and what the new set's blockers will be kept as
/// (their ids are written apart, [`BlockerMemory::begin`]).
pub struct HintSet {
    previous: Option<Arc<Blockers>>,
    from: Vec<Option<usize>>,
    places: Vec<LightPlace>,
    per_row: usize,
    rows: usize,
}

impl BlockerMemory {
    pub fn new(budget: usize) -> BlockerMemory {
        BlockerMemory {
            budget,
            last: Mutex::new(None),
            spare: Mutex::new(Vec::new()),
        }
    }

    /// The bytes of blockers kept at most.
    pub fn budget(&self) -> usize {
        self.budget
    }

    pub fn set_budget(&mut self, bytes: usize) {
        self.budget = bytes;
        *self.last.get_mut().unwrap_or_else(|e| e.into_inner()) = None;
        *self.spare.get_mut().unwrap_or_else(|e| e.into_inner()) = Vec::new();
    }

    /// Starts a light set at `places` over `rows` rows of `per_row` samples: what it reads, and
    /// the ids it writes, [`HintSet::stride`] a row (what they hold before [`HintSet::row`]
    /// fills a row is unspecified). With hints off (a budget they do not fit) no light is kept
    /// and nothing is read.
    pub fn begin(&self, places: &[LightPlace], rows: usize, per_row: usize) -> (HintSet, Vec<u32>) {
        let fits = rows
            .checked_mul(per_row)
            .and_then(|n| n.checked_mul(places.len()))
            .and_then(|n| n.checked_mul(4))
            .is_some_and(|bytes| bytes > 0 && bytes <= self.budget);
        let last = self.last.lock().unwrap_or_else(|e| e.into_inner()).clone();
        // Every light where the last set had one (a light that stays put, a dimmer, a colour
        // change): its answers are kept ([`crate::visibility`]), so next to no ray is traced,
        // and the last set's blockers serve the next as well as this set's would. Nothing is
        // read or written, and the last set's stay.
        let unmoved = last.as_ref().is_some_and(|l| {
            places.iter().all(|&at| {
                l.places
                    .iter()
                    .any(|&p| PlaceKey::from(p) == PlaceKey::from(at))
            })
        });
        let fits = fits && !unmoved;
        let kept: Vec<LightPlace> = if fits { places.to_vec() } else { Vec::new() };
        let len = rows * stride(kept.len(), per_row);
        let ids = {
            let mut spare = self.spare.lock().unwrap_or_else(|e| e.into_inner());
            // A set that keeps nothing leaves the spare to the next that does.
            if spare.len() == len {
                std::mem::take(&mut *spare)
            } else {
                vec![NONE; len]
            }
        };
        let previous =
            last.filter(|p| fits && p.rows == rows && p.per_row == per_row && !p.places.is_empty());
        let from = match &previous {
            Some(p) => places.iter().map(|&at| nearest(&p.places, at)).collect(),
            None => vec![None; places.len()],
        };
        let set = HintSet {
            previous,
            from,
            places: kept,
            per_row,
            rows,
        };
        (set, ids)
    }

    /// How many lights' blockers are kept.
    pub fn kept(&self) -> usize {
        self.last
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .map_or(0, |b| b.places.len())
    }

    /// Keeps a light set's blockers for the next; a set that kept none leaves the last one's.
    pub fn keep(&self, set: HintSet, ids: Vec<u32>) {
        if set.places.is_empty() || ids.len() != set.rows * set.stride() {
            return;
        }
        let HintSet {
            previous,
            places,
            per_row,
            rows,
            ..
        } = set;
        // This set's hold on the last set's ids goes first, so that they can become the spare.
        drop(previous);
        let kept = Blockers {
            places,
            per_row,
            rows,
            ids,
        };
        let before = self
            .last
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .replace(Arc::new(kept));
        // The set before the last's ids, unless a light set still reads them.
        if let Some(ids) = before.and_then(|b| Arc::try_unwrap(b).ok()).map(|b| b.ids) {
            *self.spare.lock().unwrap_or_else(|e| e.into_inner()) = ids;
        }
    }
}

/// Of `places`, the one of `at`'s kind nearest it: the least distance between points, the
/// least angle between beams.
fn nearest(places: &[LightPlace], at: LightPlace) -> Option<usize> {
    let gap = |p: &LightPlace| match (*p, at) {
        (LightPlace::Point(a), LightPlace::Point(b)) => Some(a.distance_squared(b)),
        (LightPlace::Beam(a), LightPlace::Beam(b)) => Some(1.0 - a.dot(b)),
        _ => None,
    };
    places
        .iter()
        .enumerate()
        .filter_map(|(i, p)| gap(p).filter(|g| g.is_finite()).map(|g| (i, g)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

impl HintSet {
    /// u32 of fresh ids a row takes.
    pub fn stride(&self) -> usize {
        stride(self.places.len(), self.per_row)
    }

    /// Row `row`'s hints, writing into `chunk` (its [`HintSet::stride`] chunk of the fresh
    /// ids). The chunk starts as each light's hints: a ray this set does not trace keeps its
    /// hint for the next (a blocked ray's blocker at a place the light stays at; at a place
    /// it left, a guess like any hint), at the cost of one copy a row rather than one a ray.
    pub fn row<'a>(&'a self, row: usize, chunk: &'a mut [u32]) -> RowHints<'a> {
        let previous = self.previous.as_deref().map(|p| {
            let stride = p.stride();
            (&p.ids[row * stride..(row + 1) * stride], p.per_row)
        });
        if !self.places.is_empty() {
            let per_row = self.per_row;
            for (light, next) in chunk.chunks_mut(per_row).enumerate() {
                let from = previous.zip(self.from.get(light).copied().flatten());
                match from {
                    Some(((ids, _), f)) => {
                        next.copy_from_slice(&ids[f * per_row..(f + 1) * per_row])
                    }
                    None => next.fill(NONE),
                }
            }
        }
        RowHints {
            previous,
            from: &self.from,
            per_row: self.per_row,
            tracked: !self.places.is_empty(),
            next: chunk,
        }
    }
}

/// One row's hints while it is lit: the last set's blockers, and this set's.
pub struct RowHints<'a> {
    previous: Option<(&'a [u32], usize)>,
    from: &'a [Option<usize>],
    per_row: usize,
    tracked: bool,
    next: &'a mut [u32],
}

impl RowHints<'_> {
    /// No hints read or kept.
    pub fn none() -> RowHints<'static> {
        RowHints {
            previous: None,
            from: &[],
            per_row: 0,
            tracked: false,
            next: &mut [],
        }
    }

    /// The blocker the last set found for sample `k` towards the light light `light` takes
    /// hints from.
    #[inline]
    pub fn hint(&self, light: usize, k: usize) -> Option<u32> {
        let (ids, per_row) = self.previous?;
        let from = (*self.from.get(light)?)?;
        ids.get(from * per_row + k).copied().filter(|&b| b != NONE)
    }

    /// Records sample `k`'s blocker towards `light` (`None`: open), traced this set.
    #[inline]
    pub fn record(&mut self, light: usize, k: usize, blocker: Option<u32>) {
        if self.tracked
            && let Some(slot) = self.next.get_mut(light * self.per_row + k)
        {
            *slot = blocker.unwrap_or(NONE);
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    #[test]
    fn hints_come_from_the_nearest_place_of_the_same_kind() {
        let memory = BlockerMemory::new(1 << 20);
        let first = [
            LightPlace::Point(Vec3::ZERO),
            LightPlace::Point(Vec3::new(10.0, 0.0, 0.0)),
            LightPlace::Beam(Vec3::NEG_Y),
        ];
        let (set, mut ids) = memory.begin(&first, 2, 4);
        let stride = set.stride();
        assert_eq!(stride, 12);
        for (row, chunk) in ids.chunks_mut(stride).enumerate() {
            let mut hints = set.row(row, chunk);
            assert_eq!(hints.hint(0, 0), None, "nothing before the first set");
            for light in 0..3 {
                for k in 0..4 {
                    let id = (row * 100 + light * 10 + k) as u32;
                    hints.record(light, k, (k != 3).then_some(id));
                }
            }
        }
        memory.keep(set, ids);

        // A point near the second, a beam, a point near the first.
        let second = [
            LightPlace::Point(Vec3::new(9.0, 0.0, 0.0)),
            LightPlace::Beam(Vec3::new(0.1, -1.0, 0.0).normalize()),
            LightPlace::Point(Vec3::new(1.0, 0.0, 0.0)),
        ];
        let (set, mut ids) = memory.begin(&second, 2, 4);
        let mut chunk = vec![NONE; set.stride()];
        let mut hints = set.row(1, &mut chunk);
        assert_eq!(hints.hint(0, 2), Some(112));
        assert_eq!(hints.hint(1, 0), Some(120));
        assert_eq!(hints.hint(2, 1), Some(101));
        assert_eq!(hints.hint(2, 3), None, "an open ray gives no hint");
        hints.record(1, 1, Some(7));
        hints.record(0, 2, None);
        // Each light's hints, copied, then what this set traced.
        assert_eq!(&chunk[..4], &[110, 111, NONE, NONE]);
        assert_eq!(&chunk[4..8], &[120, 7, 122, NONE]);
        assert_eq!(&chunk[8..], &[100, 101, 102, NONE]);
        ids[set.stride()..].copy_from_slice(&chunk);
        memory.keep(set, ids);
        // The same places again: their answers are kept, so the set reads and writes no
        // hints, and the last set's stay.
        let (set, _) = memory.begin(&second, 2, 4);
        assert_eq!(set.stride(), 1);
        let mut chunk = [NONE];
        assert_eq!(set.row(1, &mut chunk).hint(0, 1), None);
        memory.keep(set, vec![NONE; 2]);
        assert_eq!(memory.kept(), 3);
        // Moved a little: the copied hints of untraced rays, and what was traced.
        let third = [
            LightPlace::Point(Vec3::new(8.5, 0.0, 0.0)),
            LightPlace::Beam(Vec3::new(0.12, -1.0, 0.0).normalize()),
        ];
        let (set, _) = memory.begin(&third, 2, 4);
        let mut chunk = vec![NONE; set.stride()];
        let hints = set.row(1, &mut chunk);
        assert_eq!(hints.hint(0, 1), Some(111), "copied");
        assert_eq!(hints.hint(1, 1), Some(7));
    }

    #[test]
    fn hints_that_do_not_fit_are_not_kept() {
        // 2 rows × 4 samples × 1 light × 4 bytes = 32 bytes.
        let memory = BlockerMemory::new(31);
        let at = [LightPlace::Point(Vec3::ZERO)];
        let (set, ids) = memory.begin(&at, 2, 4);
        assert_eq!(set.stride(), 1);
        memory.keep(set, ids);
        let (set, _) = memory.begin(&at, 2, 4);
        let mut chunk = [NONE];
        assert_eq!(set.row(0, &mut chunk).hint(0, 0), None);
        // A row-count change reads nothing either.
        let memory = BlockerMemory::new(1 << 10);
        let (set, mut ids) = memory.begin(&at, 2, 4);
        ids.fill(3);
        memory.keep(set, ids);
        let moved = [LightPlace::Point(Vec3::X)];
        let (set, _) = memory.begin(&moved, 3, 4);
        let mut chunk = vec![NONE; set.stride()];
        assert_eq!(set.row(0, &mut chunk).hint(0, 0), None);
        let (set, _) = memory.begin(&moved, 2, 4);
        let mut chunk = vec![NONE; set.stride()];
        assert_eq!(set.row(0, &mut chunk).hint(0, 0), Some(3));
    }
}
