//! Data parallelism for the pose-grid work of loading and training a model (hidden-point
//! removal at thousands of poses): contiguous chunks on scoped threads, results in input order,
//! so the output is the same for any number of threads.

use std::num::NonZeroUsize;
use std::thread;

/// Items a thread gets at the least: below that a thread costs more than it saves.
const MIN_CHUNK: usize = 64;

/// `items.iter().map(|x| f(&mut state, x))` with one `state` from `init` per thread, on up to as
/// many threads as the process may use (`std::thread::available_parallelism`, which follows
/// cgroup CPU quotas); the results in the order of `items`. A thread the OS refuses to start
/// leaves its chunk to the calling thread. A panic in `f` is resumed on the caller.
pub fn map_with<T, S, R>(
    items: &[T],
    init: impl Fn() -> S + Sync,
    f: impl Fn(&mut S, &T) -> R + Sync,
) -> Vec<R>
where
    T: Sync,
    R: Send,
{
    let cores = thread::available_parallelism().map_or(1, NonZeroUsize::get);
    let threads = cores.min(items.len() / MIN_CHUNK).max(1);
    let (init, f) = (&init, &f);
    let run = move |part: &[T]| {
        let mut state = init();
        part.iter().map(|x| f(&mut state, x)).collect::<Vec<R>>()
    };
    if threads == 1 {
        return run(items);
    }
    let chunk = items.len().div_ceil(threads);
    thread::scope(|scope| {
        let mut parts = items.chunks(chunk);
        let first = parts.next().unwrap_or_default();
        // The other chunks on new threads, the first on this one meanwhile.
        let spawned: Vec<_> = parts
            .map(|part| {
                thread::Builder::new()
                    .spawn_scoped(scope, move || run(part))
                    .map_err(|_| part)
            })
            .collect();
        let mut out = run(first);
        out.reserve(items.len() - out.len());
        for s in spawned {
            match s {
                Ok(handle) => out.extend(
                    handle
                        .join()
                        .unwrap_or_else(|panic| std::panic::resume_unwind(panic)),
                ),
                Err(part) => out.extend(run(part)),
            }
        }
        out
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn maps_in_order_with_one_state_per_chunk(n in 0usize..1000) {
            let items: Vec<usize> = (0..n).collect();
            // The state counts the items its thread has seen: a chunk starts at zero.
            let out = map_with(&items, || 0usize, |seen, &x| { *seen += 1; (x * x, *seen) });
            prop_assert_eq!(out.len(), n);
            for (i, &(sq, _)) in out.iter().enumerate() {
                prop_assert_eq!(sq, i * i);
            }
            let starts = out.iter().filter(|&&(_, seen)| seen == 1).count();
            let cores = thread::available_parallelism().map_or(1, NonZeroUsize::get);
            let chunks = if n == 0 { 0 } else { cores.min(n / MIN_CHUNK).max(1) };
            prop_assert_eq!(starts, chunks);
        }
    }
}
