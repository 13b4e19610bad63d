//! The visibility bitset that flows between stages: bit `i` set means the object in store slot `i` may be
//! visible. Each stage reads the previous stage's set and clears bits in place, so no stage copies a list.

/// One bit per store slot, 64 slots a word; bits past [`VisibleSet::len`] are always clear.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct VisibleSet {
    words: Vec<u64>,
    len: usize,
}

impl VisibleSet {
    /// A set of `len` slots, all clear.
    pub fn new(len: usize) -> Self {
        Self { words: vec![0; len.div_ceil(64)], len }
    }

    /// A set of `len` slots, all set.
    pub fn all(len: usize) -> Self {
        let mut set = Self { words: vec![u64::MAX; len.div_ceil(64)], len };
        set.clear_tail();
        set
    }

    /// Resizes to `len` slots and clears every bit, reusing the allocation.
    pub fn reset(&mut self, len: usize) {
        self.words.clear();
        self.words.resize(len.div_ceil(64), 0);
        self.len = len;
    }

    /// Resizes to `len` slots without clearing the words it keeps, for a caller that then writes every word
    /// (with the bits past `len` clear) before the set is read: a pass over the words saved where the writes
    /// are spread over tasks.
    pub(crate) fn resize_for_overwrite(&mut self, len: usize) {
        self.words.resize(len.div_ceil(64), 0);
        self.len = len;
    }

    /// Grows or shrinks to `len` slots, keeping the bits of the slots that remain; new slots are clear.
    pub fn resize(&mut self, len: usize) {
        self.words.resize(len.div_ceil(64), 0);
        self.len = len;
        self.clear_tail();
    }

    /// Number of slots (set or not).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the set has no slots.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether slot `index` is set.
    pub fn contains(&self, index: usize) -> bool {
        index < self.len && self.words[index / 64] & (1 << (index % 64)) != 0
    }

    /// Sets or clears slot `index`.
    pub fn set(&mut self, index: usize, visible: bool) {
        let bit = 1u64 << (index % 64);
        if visible {
            self.words[index / 64] |= bit;
        } else {
            self.words[index / 64] &= !bit;
        }
    }

    /// Clears every slot set in `other` (the shorter length of the two applies).
    pub fn and_not(&mut self, other: &VisibleSet) {
        for (word, &remove) in self.words.iter_mut().zip(&other.words) {
            *word &= !remove;
        }
    }

    /// Adds every slot of `other` (their union); slots past the shorter set are left as they are.
    pub fn or(&mut self, other: &VisibleSet) {
        for (word, &add) in self.words.iter_mut().zip(&other.words) {
            *word |= add;
        }
    }

    /// Number of set slots.
    pub fn count(&self) -> usize {
        self.words.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// The raw words, 64 slots each, slot `i` at bit `i % 64` of word `i / 64`.
    pub fn words(&self) -> &[u64] {
        &self.words
    }

    /// The raw words, for stages that write the set in parallel. Callers must keep bits past `len` clear
    /// (see [`VisibleSet::clear_tail`]).
    pub fn words_mut(&mut self) -> &mut [u64] {
        &mut self.words
    }

    /// Clears the bits past `len` in the last word.
    pub fn clear_tail(&mut self) {
        if !self.len.is_multiple_of(64)
            && let Some(last) = self.words.last_mut()
        {
            *last &= (1u64 << (self.len % 64)) - 1;
        }
    }

    /// The set slots in increasing order.
    pub fn iter(&self) -> impl Iterator<Item = usize> + '_ {
        set_slots(0, &self.words)
    }
}

/// The slots set in `words`, a run of a set's [`VisibleSet::words`] starting at word `first_word`, in
/// increasing order: for stages that read a set's words in parallel chunks.
pub fn set_slots(first_word: usize, words: &[u64]) -> impl Iterator<Item = usize> + '_ {
    SetSlots { words, next_word: 0, first_word, base: 0, bits: 0 }
}

/// The iterator of [`set_slots`]: one word's bits at a time, a branch and a bit scan a slot.
struct SetSlots<'a> {
    words: &'a [u64],
    /// Index in `words` of the word after the one `bits` holds what is left of.
    next_word: usize,
    first_word: usize,
    /// The first slot of the word `bits` comes from.
    base: usize,
    bits: u64,
}

impl Iterator for SetSlots<'_> {
    type Item = usize;

    #[inline]
    fn next(&mut self) -> Option<usize> {
        while self.bits == 0 {
            self.bits = *self.words.get(self.next_word)?;
            self.base = (self.first_word + self.next_word) * 64;
            self.next_word += 1;
        }
        let bit = self.bits.trailing_zeros() as usize;
        self.bits &= self.bits - 1;
        Some(self.base + bit)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let here = self.bits.count_ones() as usize;
        (here, Some(here + 64 * (self.words.len() - self.next_word)))
    }
}

/// A [`VisibleSet`] set from several threads at once (a traversal's tasks), copied into one when they are done.
pub(crate) struct SharedVisibleSet(Vec<std::sync::atomic::AtomicU64>);

impl SharedVisibleSet {
    /// `len` slots, all clear.
    pub(crate) fn new(len: usize) -> Self {
        Self((0..len.div_ceil(64)).map(|_| std::sync::atomic::AtomicU64::new(0)).collect())
    }

    /// Sets `slot`, which must be below the length.
    pub(crate) fn set(&self, slot: u32) {
        self.0[slot as usize / 64].fetch_or(1 << (slot % 64), std::sync::atomic::Ordering::Relaxed);
    }

    /// Copies the bits into `set`, resized to `len` slots.
    pub(crate) fn copy_to(&self, len: usize, set: &mut VisibleSet) {
        set.reset(len);
        for (word, shared) in set.words_mut().iter_mut().zip(&self.0) {
            *word = shared.load(std::sync::atomic::Ordering::Relaxed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iter_and_count_agree_with_contains() {
        let mut set = VisibleSet::new(130);
        for i in [0, 5, 63, 64, 129] {
            set.set(i, true);
        }
        assert_eq!(set.iter().collect::<Vec<_>>(), vec![0, 5, 63, 64, 129]);
        assert_eq!(set.count(), 5);
        assert!(set.contains(129) && !set.contains(128) && !set.contains(500));
        let all = VisibleSet::all(130);
        assert_eq!(all.count(), 130);
        assert_eq!(all.iter().last(), Some(129));
        // The words read in chunks give the same slots, chunk after chunk.
        let chunked: Vec<usize> =
            set.words().chunks(1).enumerate().flat_map(|(chunk, words)| set_slots(chunk, words)).collect();
        assert_eq!(chunked, set.iter().collect::<Vec<_>>());
    }

    /// `set_slots` gives each set bit once, in order, from any first word, empty words between included.
    #[test]
    fn set_slots_gives_every_set_bit_in_order() {
        let words = [0, 1 << 63 | 1, 0, 0, u64::MAX, 0b1010, 0];
        for first_word in [0, 3] {
            let expected: Vec<usize> = (0..words.len() * 64)
                .filter(|&bit| words[bit / 64] >> (bit % 64) & 1 == 1)
                .map(|bit| first_word * 64 + bit)
                .collect();
            let slots = set_slots(first_word, &words);
            assert!(slots.size_hint().1.is_some_and(|most| most >= expected.len()));
            assert_eq!(slots.collect::<Vec<_>>(), expected);
        }
        assert_eq!(set_slots(2, &[]).next(), None);
    }
}
