//! A bounded cache of per-pattern results: the key is a view bin, a ridge parameter and a
//! missing-point pattern (a bit set, inline up to 256 points, so lookups do not allocate).
//! Readers share a lock; when full, the oldest entry goes. Keys are hashed with FxHash, which
//! is fast on the query path; a client choosing patterns that collide gains nothing a new
//! pattern's solve (milliseconds) does not already cost, and the map stays small.

use std::collections::VecDeque;
use std::sync::{Arc, RwLock};

use rustc_hash::FxHashMap;

/// A missing-point pattern as a bit set.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(super) enum Pattern {
    Inline([u64; 4]),
    Heap(Box<[u64]>),
}

impl Pattern {
    /// The pattern of `missing` (true = left out).
    pub(super) fn of(missing: &[bool]) -> Self {
        let set = |words: &mut [u64]| {
            for (i, &m) in missing.iter().enumerate() {
                if m {
                    words[i / 64] |= 1 << (i % 64);
                }
            }
        };
        if missing.len() <= 256 {
            let mut w = [0u64; 4];
            set(&mut w);
            Pattern::Inline(w)
        } else {
            let mut w = vec![0u64; missing.len().div_ceil(64)].into_boxed_slice();
            set(&mut w);
            Pattern::Heap(w)
        }
    }
}

/// What a cache entry is for.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(super) struct Key {
    pub bin: usize,
    pub epsilon_bits: u64,
    pub pattern: Pattern,
}

/// The entries and their insertion order.
type Entries<T> = (FxHashMap<Key, Arc<T>>, VecDeque<Key>);

/// A bounded map from [`Key`] to shared values.
#[derive(Debug)]
pub(super) struct BoundedCache<T> {
    limit: usize,
    inner: RwLock<Entries<T>>,
}

impl<T> BoundedCache<T> {
    pub(super) fn new(limit: usize) -> Self {
        BoundedCache {
            limit: limit.max(1),
            inner: RwLock::new((FxHashMap::default(), VecDeque::new())),
        }
    }

    pub(super) fn get(&self, k: &Key) -> Option<Arc<T>> {
        let g = self.inner.read().unwrap_or_else(|e| e.into_inner());
        g.0.get(k).cloned()
    }

    pub(super) fn insert(&self, k: Key, v: Arc<T>) {
        let mut g = self.inner.write().unwrap_or_else(|e| e.into_inner());
        let (map, order) = &mut *g;
        if map.insert(k.clone(), v).is_none() {
            order.push_back(k);
            while order.len() > self.limit {
                if let Some(old) = order.pop_front() {
                    map.remove(&old);
                }
            }
        }
    }

    pub(super) fn clear(&self) {
        let mut g = self.inner.write().unwrap_or_else(|e| e.into_inner());
        g.0.clear();
        g.1.clear();
    }

    pub(super) fn len(&self) -> usize {
        self.inner.read().unwrap_or_else(|e| e.into_inner()).0.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(bin: usize, missing: &[bool]) -> Key {
        Key {
            bin,
            epsilon_bits: 1.0f64.to_bits(),
            pattern: Pattern::of(missing),
        }
    }

    #[test]
    fn patterns_tell_apart_sets_and_sizes() {
        assert_eq!(Pattern::of(&[true, false]), Pattern::of(&[true, false]));
        assert_ne!(Pattern::of(&[true, false]), Pattern::of(&[false, true]));
        let mut big = vec![false; 300];
        big[299] = true;
        assert!(matches!(Pattern::of(&big), Pattern::Heap(_)));
        assert_ne!(Pattern::of(&big), Pattern::of(&vec![false; 300]));
    }

    #[test]
    fn the_oldest_entry_goes_when_full() {
        let c = BoundedCache::new(2);
        c.insert(key(0, &[true]), Arc::new(1));
        c.insert(key(1, &[true]), Arc::new(2));
        c.insert(key(2, &[true]), Arc::new(3));
        assert_eq!(c.len(), 2);
        assert!(c.get(&key(0, &[true])).is_none());
        assert_eq!(c.get(&key(2, &[true])).as_deref(), Some(&3));
        c.clear();
        assert_eq!(c.len(), 0);
    }
}
