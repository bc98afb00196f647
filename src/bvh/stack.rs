//! The traversal stack every tree walk uses: a fixed array on the call stack that is *not* zeroed when a query
//! starts. A walk of the 4-wide tree keeps room for 193 entries (1.5 KB) of which a typical ray touches a
//! handful; zeroing them was a visible `memset` per ray in shadow-ray profiles. Capacity is the tree depth
//! bound ([`MAX_DEPTH`](super::MAX_DEPTH)) times the siblings a level can push, so a push past it is a bug in a
//! builder, caught by the bounds check.

use std::mem::MaybeUninit;

/// A last-in-first-out stack of at most `N` copyable entries, created without touching its memory.
pub(crate) struct Stack<T: Copy, const N: usize> {
    items: [MaybeUninit<T>; N],
    len: usize,
}

impl<T: Copy, const N: usize> Stack<T, N> {
    /// An empty stack. Costs nothing: the entries are left uninitialised.
    #[inline(always)]
    pub(crate) fn new() -> Self {
        Stack {
            items: [const { MaybeUninit::uninit() }; N],
            len: 0,
        }
    }

    /// Pushes `x`. Panics when the stack already holds `N` entries (a tree deeper than its builder allows).
    #[inline(always)]
    pub(crate) fn push(&mut self, x: T) {
        self.items[self.len].write(x);
        self.len += 1;
    }

    /// Writes `items` above the top and keeps the first `n` of them (at most `M`) pushed: a push of a
    /// varying count without a branch per entry. Panics when the `M` entries would not fit.
    #[inline(always)]
    pub(crate) fn push_first<const M: usize>(&mut self, items: [T; M], n: usize) {
        for (slot, x) in self.items[self.len..self.len + M].iter_mut().zip(items) {
            slot.write(x);
        }
        self.len += n.min(M);
    }

    /// Empties the stack.
    #[inline(always)]
    pub(crate) fn clear(&mut self) {
        self.len = 0;
    }

    /// Pops the entry pushed last, or `None` when the stack is empty.
    #[inline(always)]
    pub(crate) fn pop(&mut self) -> Option<T> {
        self.len = self.len.checked_sub(1)?;
        // SAFETY: entries below the old length were written by `push` and never moved out (`T: Copy`).
        Some(unsafe { self.items[self.len].assume_init() })
    }
}

#[cfg(test)]
mod tests {
    use super::Stack;

    #[test]
    fn pops_in_reverse_push_order_and_then_none() {
        let mut s = Stack::<(u32, f32), 4>::new();
        assert_eq!(s.pop(), None);
        for i in 0..4 {
            s.push((i, i as f32 * 0.5));
        }
        for i in (0..4).rev() {
            assert_eq!(s.pop(), Some((i, i as f32 * 0.5)));
        }
        assert_eq!(s.pop(), None);
        s.push((9, 1.0));
        assert_eq!(s.pop(), Some((9, 1.0)));
    }

    /// `push_first` keeps the first `n` of its entries, in order, on top of what was there.
    #[test]
    fn push_first_keeps_the_first_n() {
        let mut s = Stack::<u32, 8>::new();
        s.push(7);
        s.push_first([1, 2, 3], 2);
        s.push_first([4, 5, 6], 0);
        s.push_first([8, 9, 10], 1);
        let popped: Vec<u32> = std::iter::from_fn(|| s.pop()).collect();
        assert_eq!(popped, [8, 2, 1, 7]);
    }

    #[test]
    #[should_panic]
    fn a_push_past_capacity_panics() {
        let mut s = Stack::<u32, 2>::new();
        for i in 0..3 {
            s.push(i);
        }
    }
}
