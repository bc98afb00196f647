//! The few parallel primitives the crate uses: rayon's when the `parallel` feature is on, sequential
//! stand-ins with the same results otherwise. Every caller is deterministic either way.

/// Runs both closures, in parallel when the feature is on and `parallel` is true.
#[inline]
pub(crate) fn join<A, B, RA, RB>(parallel: bool, a: A, b: B) -> (RA, RB)
where
    A: FnOnce() -> RA + Send,
    B: FnOnce() -> RB + Send,
    RA: Send,
    RB: Send,
{
    #[cfg(feature = "parallel")]
    if parallel {
        return rayon::join(a, b);
    }
    let _ = parallel;
    (a(), b())
}

/// Sets `out[i] = f(i)` for every index, in parallel chunks of `chunk` when asked.
pub(crate) fn fill<T: Send>(
    parallel: bool,
    out: &mut [T],
    chunk: usize,
    f: impl Fn(usize) -> T + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if parallel {
        use rayon::prelude::*;
        let chunk = chunk.max(1);
        out.par_chunks_mut(chunk).enumerate().for_each(|(c, o)| {
            for (j, x) in o.iter_mut().enumerate() {
                *x = f(c * chunk + j);
            }
        });
        return;
    }
    let _ = (parallel, chunk);
    for (i, x) in out.iter_mut().enumerate() {
        *x = f(i);
    }
}

/// Appends `f(x)` for every `x` of `input` to `out`, in order, in parallel chunks of `chunk` when asked:
/// straight into `out`'s spare room (no first pass that zeroes it), no allocation when it has room.
pub(crate) fn extend_mapped<I: Sync, T: Send>(
    parallel: bool,
    out: &mut Vec<T>,
    input: &[I],
    chunk: usize,
    f: impl Fn(&I) -> T + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if parallel {
        use rayon::prelude::*;
        out.par_extend(input.par_iter().with_min_len(chunk.max(1)).map(f));
        return;
    }
    let _ = (parallel, chunk);
    out.extend(input.iter().map(f));
}

/// Maps every chunk of `input` with `map` and folds the results with `reduce` (in chunk order).
pub(crate) fn map_reduce<I: Sync, R>(
    parallel: bool,
    input: &[I],
    chunk: usize,
    identity: R,
    map: impl Fn(&[I]) -> R + Sync + Send,
    reduce: impl Fn(R, R) -> R + Sync + Send,
) -> R
where
    R: Clone + Send + Sync,
{
    let chunk = chunk.max(1);
    #[cfg(feature = "parallel")]
    if parallel {
        use rayon::prelude::*;
        return input
            .par_chunks(chunk)
            .map(&map)
            .reduce(|| identity.clone(), &reduce);
    }
    let _ = parallel;
    input.chunks(chunk).map(map).fold(identity, reduce)
}

/// Calls `f(i, &mut items[i])` for every item, in parallel when the feature is on and `parallel` is true.
pub(crate) fn for_each_mut<T: Send>(
    parallel: bool,
    items: &mut [T],
    f: impl Fn(usize, &mut T) + Sync + Send,
) {
    for_each_mut_split(parallel, items, usize::MAX, f);
}

/// [`for_each_mut`] with a task per item: for a few heavy items of uneven cost (meshes to refit), which the
/// pool's split into halves can leave mostly to one thread.
pub(crate) fn for_each_mut_one_by_one<T: Send>(
    parallel: bool,
    items: &mut [T],
    f: impl Fn(usize, &mut T) + Sync + Send,
) {
    for_each_mut_split(parallel, items, 1, f);
}

/// `f(i, &mut items[i])` for every item, at most `per_task` items to a task (`usize::MAX`: as the pool
/// splits). No allocation of its own.
fn for_each_mut_split<T: Send>(
    parallel: bool,
    items: &mut [T],
    per_task: usize,
    f: impl Fn(usize, &mut T) + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if parallel {
        use rayon::prelude::*;
        (items.par_iter_mut().with_max_len(per_task))
            .enumerate()
            .for_each(|(i, x)| f(i, x));
        return;
    }
    let _ = (parallel, per_task);
    for (i, x) in items.iter_mut().enumerate() {
        f(i, x);
    }
}

/// Worker threads parallel work may use (1 without the feature).
pub(crate) fn threads() -> usize {
    #[cfg(feature = "parallel")]
    return rayon::current_num_threads();
    #[cfg(not(feature = "parallel"))]
    1
}

/// [`fill_chunks`] with a state per chunk: calls `f(c, chunk, &mut state[c])` (`state` needs at least one
/// item per chunk), e.g. a list per chunk that is concatenated afterwards.
pub(crate) fn fill_chunks_with<T: Send, S: Send>(
    parallel: bool,
    out: &mut [T],
    chunk: usize,
    state: &mut [S],
    f: impl Fn(usize, &mut [T], &mut S) + Sync + Send,
) {
    let chunk = chunk.max(1);
    assert!(
        state.len() >= out.len().div_ceil(chunk),
        "one state per chunk"
    );
    #[cfg(feature = "parallel")]
    if parallel {
        use rayon::prelude::*;
        out.par_chunks_mut(chunk)
            .zip(state.par_iter_mut())
            .enumerate()
            .for_each(|(c, (o, s))| f(c, o, s));
        return;
    }
    let _ = parallel;
    for (c, (o, s)) in out.chunks_mut(chunk).zip(state).enumerate() {
        f(c, o, s);
    }
}

/// Calls `f(c, chunk)` for every chunk `c` of `chunk` items of `out` (the last may be shorter), in parallel
/// when the feature is on and `parallel` is true.
pub(crate) fn fill_chunks<T: Send>(
    parallel: bool,
    out: &mut [T],
    chunk: usize,
    f: impl Fn(usize, &mut [T]) + Sync + Send,
) {
    let chunk = chunk.max(1);
    #[cfg(feature = "parallel")]
    if parallel {
        use rayon::prelude::*;
        out.par_chunks_mut(chunk)
            .enumerate()
            .for_each(|(c, o)| f(c, o));
        return;
    }
    let _ = parallel;
    for (c, o) in out.chunks_mut(chunk).enumerate() {
        f(c, o);
    }
}
