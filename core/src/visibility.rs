//! Shadow-ray answers kept from one light set to the next.
//!
//! This module owns one saving of the CPU's direct light ([`crate::direct`]) on a
//! surface-geometry scene: it never changes a value. Whether a sample point's shadow ray
//! towards a light is blocked depends on the point, the scene's triangles and the place the
//! light stands ([`LightPlace`]: a point or spot light's position, a directional light's
//! direction) and on nothing else: not the light's colour, intensity, range or cone, which only
//! decide whether a ray is needed and what an open one brings. So per place, the answers of the
//! rays traced are kept as two bits a sample point ([`Visibility`]: traced, and open), and a
//! light set that has a light where an earlier set had one (a lamp that stays put while another
//! moves, a dimmer, a colour change, a sun that several sessions share) traces only the rays
//! that set did not. A light that moves traces every ray, as before.
//!
//! The price is memory, about 2 × ⌈samples a row / 32⌉ × 4 bytes a row a place (94 KB for
//! `pandora`'s 11,810 rows at 32 samples), within a budget per scene ([`DEFAULT_BUDGET`]); the
//! places of the light set being lit are never the ones evicted.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use glam::Vec3;

/// Where a light's shadow rays run: what their answers depend on besides the sample points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightPlace {
    /// A point or spot light at this position: rays run to it.
    Point(Vec3),
    /// A directional light whose light travels along this unit axis: rays run against it.
    Beam(Vec3),
}

/// A place as exact bits: two places share answers only if every ray is the same ray.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PlaceKey {
    beam: bool,
    place: [u32; 3],
}

impl From<LightPlace> for PlaceKey {
    fn from(place: LightPlace) -> PlaceKey {
        let (beam, at) = match place {
            LightPlace::Point(p) => (false, p),
            LightPlace::Beam(axis) => (true, axis),
        };
        PlaceKey {
            beam,
            place: at.to_array().map(f32::to_bits),
        }
    }
}

/// Bytes of answers a scene keeps unless told otherwise: 32 MiB, about 350 places of `pandora`
/// at 32 samples a row, 70 of a 20,000-patch scene's 60,000 rows.
pub const DEFAULT_BUDGET: usize = 32 << 20;

/// The answers of one place's shadow rays, per row `words` u32 of "traced" bits then `words` of
/// "open" bits, bit `k % 32` of word `k / 32` for the row's sample `k`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Visibility {
    words: usize,
    bits: Vec<u32>,
}

impl Visibility {
    /// u32 words a row holds for each of the two kinds of bits, for `per_row` samples a row.
    pub fn words_for(per_row: usize) -> usize {
        per_row.div_ceil(32)
    }

    /// The row's bits, `2 × words` u32: traced then open.
    pub fn row(&self, row: usize) -> &[u32] {
        &self.bits[row * 2 * self.words..(row + 1) * 2 * self.words]
    }

    fn bytes(&self) -> usize {
        self.bits.len() * 4
    }
}

/// One light set's answers being written: per row, per tracked light, the place's bits as
/// [`Visibility`] lays them out, rows one after another so each row is a chunk of its own
/// ([`Fresh::stride`] u32, one unused word a row where no light is tracked, so that rows can
/// still be taken as chunks).
pub struct Fresh {
    words: usize,
    lights: usize,
    pub bits: Vec<u32>,
}

impl Fresh {
    /// u32 a row takes: each tracked light's traced and open words, at least 1.
    pub fn stride(&self) -> usize {
        (self.lights * 2 * self.words).max(1)
    }

    /// The words per row of each kind of bits for [`RowBits::new`]: 0 where no light is
    /// tracked.
    pub fn tracked_words(&self) -> usize {
        if self.lights == 0 { 0 } else { self.words }
    }
}

/// Reads and writes one row's answers for every tracked light while the row is lit: the
/// answers known before, and the ones its rays add.
pub struct RowBits<'a> {
    words: usize,
    bits: &'a mut [u32],
}

impl RowBits<'_> {
    /// A row's chunk of [`Fresh::bits`] with [`Fresh::tracked_words`].
    pub fn new(words: usize, chunk: &mut [u32]) -> RowBits<'_> {
        RowBits { words, bits: chunk }
    }

    /// No tracking: every ray is traced and nothing is kept.
    pub fn none() -> RowBits<'static> {
        RowBits {
            words: 0,
            bits: &mut [],
        }
    }

    /// What is known of sample `k`'s ray towards light `light`: `Some(open)` if it was traced.
    #[inline]
    pub fn known(&self, light: usize, k: usize) -> Option<bool> {
        let (base, w, bit) = self.at(light, k)?;
        (self.bits[base + w] & bit != 0).then(|| self.bits[base + self.words + w] & bit != 0)
    }

    /// Records that sample `k`'s ray towards light `light` was traced, and whether it was open.
    #[inline]
    pub fn record(&mut self, light: usize, k: usize, open: bool) {
        if let Some((base, w, bit)) = self.at(light, k) {
            self.bits[base + w] |= bit;
            if open {
                self.bits[base + self.words + w] |= bit;
            }
        }
    }

    /// Where the bits of (light, k) are, if that light is tracked and `k` fits the row.
    #[inline]
    fn at(&self, light: usize, k: usize) -> Option<(usize, usize, u32)> {
        let (w, base) = (k / 32, light * 2 * self.words);
        (w < self.words && base + 2 * self.words <= self.bits.len()).then_some((
            base,
            w,
            1u32 << (k % 32),
        ))
    }
}

/// A scene's kept answers: the places of the last light sets, most recent last.
pub struct VisibilityCache {
    budget: usize,
    kept: Mutex<VecDeque<(PlaceKey, Arc<Visibility>)>>,
}

impl VisibilityCache {
    /// A cache of at most `budget` bytes (0 keeps nothing, so every ray is traced).
    pub fn new(budget: usize) -> VisibilityCache {
        VisibilityCache {
            budget,
            kept: Mutex::new(VecDeque::new()),
        }
    }

    pub fn budget(&self) -> usize {
        self.budget
    }

    /// Sets the budget and forgets what was kept.
    pub fn set_budget(&mut self, budget: usize) {
        self.budget = budget;
        self.kept
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
    }

    /// How many places have answers kept.
    pub fn kept(&self) -> usize {
        self.lock().len()
    }

    // A poisoned lock only means another thread panicked while holding it: what it holds is
    // whole (an entry is complete before it is inserted).
    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<(PlaceKey, Arc<Visibility>)>> {
        self.kept.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Starts a light set of lights at `places` over `rows` rows of `per_row` samples: what is
    /// known of each place, and a buffer for this set's answers, holding the known ones
    /// already. Only as many of the set's first lights are tracked as the budget holds; the
    /// rest are traced, and their answers not kept.
    pub fn begin(&self, places: &[LightPlace], rows: usize, per_row: usize) -> Fresh {
        let words = Visibility::words_for(per_row);
        let per_place = rows * 2 * words * 4;
        let lights = self
            .budget
            .checked_div(per_place)
            .map_or(0, |fit| places.len().min(fit));
        let stride = (lights * 2 * words).max(1);
        let mut fresh = Fresh {
            words,
            lights,
            bits: vec![0; rows * stride],
        };
        if lights == 0 {
            return fresh;
        }
        let known: Vec<Option<Arc<Visibility>>> = {
            let kept = self.lock();
            places[..lights]
                .iter()
                .map(|&p| {
                    let key = PlaceKey::from(p);
                    kept.iter()
                        .find(|(k, v)| {
                            *k == key && v.words == words && v.bits.len() == rows * 2 * words
                        })
                        .map(|(_, v)| Arc::clone(v))
                })
                .collect()
        };
        for (j, known) in known.iter().enumerate() {
            let Some(known) = known else { continue };
            for (row, chunk) in fresh.bits.chunks_mut(stride).enumerate() {
                chunk[j * 2 * words..(j + 1) * 2 * words].copy_from_slice(known.row(row));
            }
        }
        fresh
    }

    /// Keeps the answers of a light set that [`VisibilityCache::begin`] started, in place of
    /// the older answers of its places, and evicts the least recently used other places
    /// while over budget.
    pub fn keep(&self, places: &[LightPlace], fresh: Fresh) {
        if fresh.lights == 0 {
            return;
        }
        let (words, row_len) = (fresh.words, fresh.stride());
        let rows = fresh.bits.len() / row_len;
        let keys: Vec<PlaceKey> = places[..fresh.lights].iter().map(|&p| p.into()).collect();
        let mut merged: Vec<(PlaceKey, Vec<u32>)> = Vec::with_capacity(keys.len());
        for (j, &key) in keys.iter().enumerate() {
            let slot = j * 2 * words..(j + 1) * 2 * words;
            match merged.iter_mut().find(|(k, _)| *k == key) {
                // Two lights at one place in one set (a spot where a point light stands) traced
                // rays each the other may not have: the same ray has the same answer, so their
                // bits join.
                Some((_, bits)) => {
                    for (row, chunk) in fresh.bits.chunks(row_len).enumerate() {
                        let at = row * 2 * words;
                        for (b, &f) in bits[at..at + 2 * words]
                            .iter_mut()
                            .zip(&chunk[slot.clone()])
                        {
                            *b |= f;
                        }
                    }
                }
                None => {
                    let mut bits = Vec::with_capacity(rows * 2 * words);
                    for chunk in fresh.bits.chunks(row_len) {
                        bits.extend_from_slice(&chunk[slot.clone()]);
                    }
                    merged.push((key, bits));
                }
            }
        }
        let entries: Vec<(PlaceKey, Arc<Visibility>)> = merged
            .into_iter()
            .map(|(key, bits)| (key, Arc::new(Visibility { words, bits })))
            .collect();
        let mut kept = self.lock();
        kept.retain(|(k, _)| !keys.contains(k));
        kept.extend(entries);
        let mut bytes: usize = kept.iter().map(|(_, v)| v.bytes()).sum();
        while bytes > self.budget {
            let Some(at) = kept.iter().position(|(k, _)| !keys.contains(k)) else {
                break;
            };
            if let Some((_, v)) = kept.remove(at) {
                bytes -= v.bytes();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_round_trip_and_are_kept_per_place() {
        let cache = VisibilityCache::new(DEFAULT_BUDGET);
        let lamp = LightPlace::Point(Vec3::new(1.0, 2.0, 3.0));
        let sun = LightPlace::Beam(Vec3::NEG_Y);
        let (rows, per_row) = (5, 40);
        let mut fresh = cache.begin(&[lamp, sun], rows, per_row);
        let (words, row_len) = (fresh.tracked_words(), fresh.stride());
        assert_eq!((words, row_len), (2, 8));
        for (row, chunk) in fresh.bits.chunks_mut(row_len).enumerate() {
            let mut bits = RowBits::new(words, chunk);
            assert_eq!(bits.known(0, 3), None);
            bits.record(0, 3 + row, row % 2 == 0);
            bits.record(1, 39, true);
            // Past the row's samples, or a light not tracked: nothing is kept.
            bits.record(0, 64, true);
            bits.record(2, 0, true);
            assert_eq!(bits.known(2, 0), None);
        }
        cache.keep(&[lamp, sun], fresh);
        assert_eq!(cache.kept(), 2);
        // A later set with the sun first and the lamp elsewhere: the sun's answers come back.
        let moved = LightPlace::Point(Vec3::new(1.0, 2.0, 3.5));
        let mut again = cache.begin(&[sun, moved], rows, per_row);
        let stride = again.stride();
        for (row, chunk) in again.bits.chunks_mut(stride).enumerate() {
            let bits = RowBits::new(words, chunk);
            assert_eq!(bits.known(0, 39), Some(true));
            assert_eq!(bits.known(0, 38), None);
            assert_eq!(bits.known(1, 3 + row), None);
        }
        let mut lamp_again = cache.begin(&[lamp], rows, per_row);
        assert_eq!(lamp_again.stride(), 4);
        for (row, chunk) in lamp_again.bits.chunks_mut(4).enumerate() {
            let bits = RowBits::new(words, chunk);
            assert_eq!(bits.known(0, 3 + row), Some(row % 2 == 0));
        }
        // Another row count (another file) does not read them.
        let other = cache.begin(&[lamp], rows + 1, per_row);
        assert!(other.bits.iter().all(|&b| b == 0));
        // Two lights at one place in one set: what each traced is kept.
        let mut twice = cache.begin(&[lamp, lamp], rows, per_row);
        let stride = twice.stride();
        for chunk in twice.bits.chunks_mut(stride) {
            let mut bits = RowBits::new(words, chunk);
            bits.record(0, 20, true);
            bits.record(1, 21, false);
        }
        cache.keep(&[lamp, lamp], twice);
        let mut after = cache.begin(&[lamp], rows, per_row);
        for (row, chunk) in after.bits.chunks_mut(4).enumerate() {
            let bits = RowBits::new(words, chunk);
            assert_eq!(bits.known(0, 20), Some(true));
            assert_eq!(bits.known(0, 21), Some(false));
            assert_eq!(bits.known(0, 3 + row), Some(row % 2 == 0));
        }
        assert_eq!(cache.kept(), 2);
    }

    #[test]
    fn the_budget_evicts_the_oldest_places_not_in_the_set() {
        let (rows, per_row) = (100, 32);
        // Room for three places.
        let cache = VisibilityCache::new(3 * rows * 2 * 4);
        let place = |x: f32| LightPlace::Point(Vec3::new(x, 0.0, 0.0));
        for x in 0..3 {
            let f = cache.begin(&[place(x as f32)], rows, per_row);
            cache.keep(&[place(x as f32)], f);
        }
        assert_eq!(cache.kept(), 3);
        let set = [place(0.0), place(9.0)];
        let f = cache.begin(&set, rows, per_row);
        cache.keep(&set, f);
        // Place 1, the oldest not in the set, went; place 0 stayed, as the set uses it.
        let kept: Vec<PlaceKey> = cache.lock().iter().map(|(k, _)| *k).collect();
        assert_eq!(kept.len(), 3);
        assert!(kept.contains(&place(0.0).into()) && kept.contains(&place(9.0).into()));
        assert!(!kept.contains(&place(1.0).into()));
        // A set larger than the budget tracks only the lights that fit.
        let big: Vec<LightPlace> = (10..20).map(|x| place(x as f32)).collect();
        let f = cache.begin(&big, rows, per_row);
        assert_eq!(f.lights, 3);
        // No budget, no tracking: a word a row, never written.
        let none = VisibilityCache::new(0).begin(&big, rows, per_row);
        assert_eq!(
            (none.lights, none.tracked_words(), none.stride()),
            (0, 0, 1)
        );
        assert_eq!(none.bits.len(), rows);
    }
}
