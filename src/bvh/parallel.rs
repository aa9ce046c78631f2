//! Parallel bottom-up passes over a tree with parent links (Karras 2012, section 4: "one thread
//! per leaf walks up; the first thread to reach a node stops, the second processes it").
//!
//! Used to compute boxes after LBVH, to refit after reinsertion, and for the leaf-collapse costs.
//! The writes go through raw pointers: each node is written by exactly one thread, the one that
//! arrives second at it, after both children are final. The `AcqRel` visit counter makes the
//! first child's write visible to that thread.

use std::marker::PhantomData;
use std::sync::atomic::{AtomicU32, Ordering};

use rayon::prelude::*;

use super::INVALID_INDEX;

/// A slice that several threads write at distinct indices.
pub(crate) struct SharedSlice<'a, T> {
    ptr: *mut T,
    len: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: access goes through the unsafe `get`/`set`, whose callers guarantee that no index is
// written while another thread reads or writes it.
unsafe impl<T: Send> Send for SharedSlice<'_, T> {}
unsafe impl<T: Send> Sync for SharedSlice<'_, T> {}

impl<'a, T: Copy> SharedSlice<'a, T> {
    pub(crate) fn new(slice: &'a mut [T]) -> Self {
        Self { ptr: slice.as_mut_ptr(), len: slice.len(), _borrow: PhantomData }
    }

    /// # Safety
    /// No other thread writes index `i` concurrently.
    #[inline]
    pub(crate) unsafe fn get(&self, i: usize) -> T {
        assert!(i < self.len, "SharedSlice index {i} out of bounds {}", self.len);
        // SAFETY: in bounds (checked); no concurrent writer (caller's contract).
        unsafe { self.ptr.add(i).read() }
    }

    /// # Safety
    /// No other thread reads or writes index `i` concurrently.
    #[inline]
    pub(crate) unsafe fn set(&self, i: usize, value: T) {
        assert!(i < self.len, "SharedSlice index {i} out of bounds {}", self.len);
        // SAFETY: in bounds (checked); exclusive access to `i` (caller's contract).
        unsafe { self.ptr.add(i).write(value) }
    }
}

/// Calls `visit(node)` once for every node, children before parents, in parallel.
///
/// The walk starts at each leaf yielded by `leaves` (which must yield every leaf exactly once,
/// and is best given in an order where neighbours share ancestors) and climbs `parents`. When
/// `visit(p)` runs for an internal node `p`, both of `p`'s children have been visited, their
/// writes are visible, and nothing else touches `p` concurrently: the callback may read the
/// children's entries and write `p`'s through a [`SharedSlice`]. The tree must be valid (every
/// internal node has exactly two children that name it as parent); otherwise nodes may be
/// visited early or twice.
///
/// `visits` is scratch memory for the counters, kept by callers that run this repeatedly.
pub(crate) fn bottom_up(
    parents: &[u32],
    visits: &mut Vec<AtomicU32>,
    leaves: impl IndexedParallelIterator<Item = u32>,
    visit: impl Fn(usize) + Sync,
) {
    visits.truncate(parents.len());
    visits.par_iter_mut().with_min_len(4096).for_each(|v| *v.get_mut() = 0);
    let missing = parents.len() - visits.len();
    visits.par_extend(rayon::iter::repeat_n(0, missing).map(AtomicU32::new));
    leaves.with_min_len(256).for_each(|leaf| {
        visit(leaf as usize);
        let mut node = parents[leaf as usize];
        while node != INVALID_INDEX {
            // The first child to arrive stops; its writes are released to the second.
            if visits[node as usize].fetch_add(1, Ordering::AcqRel) == 0 {
                return;
            }
            visit(node as usize);
            node = parents[node as usize];
        }
    });
}
