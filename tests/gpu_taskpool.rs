//! The GPU task pool of seed 004 (`kinetrace::gpu::taskpool`) on its toy task, a recursive halving of a range
//! into a tree whose tasks sum their ranges in work chunks: the tree read back equals the one a plain CPU
//! recursion builds (ranges, parents, depths, sums), across sizes, leaf sizes and chunk sizes that make
//! tasks of zero, one and many chunks; a pool too small fails with `Error::TaskPoolFull`. Runs on lavapipe
//! in CI (`KINETRACE_REQUIRE_GPU=1` makes a missing adapter a failure; without it the tests skip).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use kinetrace::Error;
use kinetrace::gpu::taskpool::{SumTask, sum_tree};

/// A task as the oracle sees it: (range, parent range, depth, sum).
type Task = ((u32, u32), Option<(u32, u32)>, u32, u32);

/// The CPU oracle: the same halving by recursion.
fn cpu_tree(
    values: &[u32],
    range: (u32, u32),
    parent: Option<(u32, u32)>,
    depth: u32,
    leaf: u32,
    out: &mut Vec<Task>,
) {
    let (lo, hi) = range;
    let sum = values[lo as usize..hi as usize]
        .iter()
        .fold(0u32, |a, &v| a.wrapping_add(v));
    out.push((range, parent, depth, sum));
    if hi - lo > leaf {
        let mid = lo + (hi - lo) / 2;
        cpu_tree(values, (lo, mid), Some(range), depth + 1, leaf, out);
        cpu_tree(values, (mid, hi), Some(range), depth + 1, leaf, out);
    }
}

/// Pseudo-random values (an LCG), large enough that sums wrap.
fn values(n: usize) -> Vec<u32> {
    let mut x = 0x9e37_79b9u32;
    (0..n)
        .map(|_| {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            x
        })
        .collect()
}

/// GPU tasks in the oracle's terms, sorted; also checks the child links the GPU wrote.
fn as_oracle(tasks: &[SumTask]) -> Vec<Task> {
    for (id, t) in tasks.iter().enumerate() {
        if let Some(c) = t.first_child {
            for child in [c, c + 1] {
                assert_eq!(tasks[child as usize].parent, Some(id as u32));
            }
            let (l, r) = (tasks[c as usize].range, tasks[c as usize + 1].range);
            assert_eq!((l.0, l.1, r.1), (t.range.0, r.0, t.range.1));
        }
    }
    let mut v: Vec<_> = tasks
        .iter()
        .map(|t| {
            let parent = t.parent.map(|p| tasks[p as usize].range);
            (t.range, parent, t.depth, t.sum)
        })
        .collect();
    v.sort();
    v
}

#[test]
fn sum_tree_equals_cpu_recursion() {
    let Some(gpu) = gpu_or_skip() else { return };
    for n in [0usize, 1, 2, 3, 31, 32, 33, 1023, 1025, 20_000] {
        for (leaf, chunk) in [(1, 1), (4, 3), (64, 256), (1000, 7)] {
            let v = values(n);
            let (tasks, counts) = sum_tree(&gpu, &v, leaf, chunk, 4 * n as u32 + 1).unwrap();
            let mut want = Vec::new();
            cpu_tree(&v, (0, n as u32), None, 0, leaf, &mut want);
            want.sort();
            let got = as_oracle(&tasks);
            let first_diff = got.iter().zip(&want).position(|(g, w)| g != w);
            assert!(
                got.len() == want.len() && first_diff.is_none(),
                "n {n} leaf {leaf} chunk {chunk}: {} tasks for {}, first difference at {first_diff:?}: {:?} vs {:?}",
                got.len(),
                want.len(),
                first_diff.map(|i| got[i]),
                first_diff.map(|i| want[i]),
            );
            let depth = want.iter().map(|t| t.2).max().unwrap();
            assert_eq!(counts.rounds, depth + 1, "one round per level");
            let chunks: u32 = want.iter().map(|t| (t.0.1 - t.0.0).div_ceil(chunk)).sum();
            assert_eq!(counts.chunks, chunks, "every chunk ran once");
        }
    }
}

#[test]
fn pool_too_small_is_an_error() {
    let Some(gpu) = gpu_or_skip() else { return };
    let v = values(1000);
    // Halving 1000 elements down to 1 needs 1999 tasks.
    let (tasks, _) = sum_tree(&gpu, &v, 1, 16, 1999).unwrap();
    assert_eq!(tasks.len(), 1999);
    match sum_tree(&gpu, &v, 1, 16, 1998) {
        Err(Error::TaskPoolFull { capacity, asked }) => {
            assert_eq!(capacity, 1998);
            assert!(asked > capacity);
        }
        other => panic!("expected TaskPoolFull, got {other:?}"),
    }
    assert!(matches!(
        sum_tree(&gpu, &v, 1, 16, 0),
        Err(Error::InvalidOption(_))
    ));
}

/// Past 2^16 tasks (32768 live tasks and chunks in one round): a work kernel whose few persistent
/// workgroups claimed every chunk ran past llvmpipe's 65535 loop iterations per invocation, and 8 chunks
/// were summed into the wrong task. Each invocation now claims a bounded number of chunks.
#[test]
fn sum_tree_past_two_to_the_sixteen_tasks() {
    let Some(gpu) = gpu_or_skip() else { return };
    let n = 32769;
    let v = values(n);
    let (tasks, counts) = sum_tree(&gpu, &v, 1, 1, 2 * n as u32).unwrap();
    let mut want = Vec::new();
    cpu_tree(&v, (0, n as u32), None, 0, 1, &mut want);
    want.sort();
    let got = as_oracle(&tasks);
    let wrong = got.iter().zip(&want).filter(|(g, w)| g != w).count();
    assert!(
        got.len() == want.len() && wrong == 0,
        "{wrong} tasks differ"
    );
    assert_eq!(counts.chunks, 16 * n as u32 + 2, "every chunk ran once");
}
