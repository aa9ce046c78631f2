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

/// Computes `values[i]` for every node bottom-up in parallel:
/// `values[leaf] = leaf(leaf)`, `values[p] = internal(p, values[l], values[l + 1])`.
///
/// `left_child(i)` is `None` for a leaf and the left child for an internal node; `parents` must
/// be the parent links of that same tree, which must be valid (every internal node has exactly
/// two children that name it as parent). Panics if the tree has more than `u32::MAX` nodes.
pub(crate) fn bottom_up<T, L, I>(
    parents: &[u32],
    left_child: impl Fn(usize) -> Option<usize> + Sync,
    values: &mut [T],
    leaf: L,
    internal: I,
) where
    T: Copy + Send + Sync,
    L: Fn(usize) -> T + Sync,
    I: Fn(usize, T, T) -> T + Sync,
{
    assert_eq!(parents.len(), values.len(), "one value per node");
    let visits: Vec<AtomicU32> = (0..parents.len()).map(|_| AtomicU32::new(0)).collect();
    let out = SharedSlice::new(values);
    (0..parents.len()).into_par_iter().with_min_len(256).for_each(|start| {
        if left_child(start).is_some() {
            return;
        }
        // SAFETY: a leaf is written only by the thread that starts at it.
        unsafe { out.set(start, leaf(start)) };
        let mut node = parents[start];
        while node != INVALID_INDEX {
            // The first child to arrive stops; its write is released to the second.
            if visits[node as usize].fetch_add(1, Ordering::AcqRel) == 0 {
                return;
            }
            let l = left_child(node as usize).expect("a parent is an internal node");
            // SAFETY: both children are final (this thread wrote one, the acquire above made
            // the other visible) and nothing writes them again; `node` is written only here,
            // by the second arrival, and read by others only after their own acquire.
            unsafe {
                let v = internal(node as usize, out.get(l), out.get(l + 1));
                out.set(node as usize, v);
            }
            node = parents[node as usize];
        }
    });
}
