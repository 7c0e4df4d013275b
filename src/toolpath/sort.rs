//! In-place unstable sort with a small, fixed stack frame.
//!
//! An iterative quicksort (pivot the median of three, Hoare partition that stops on equal keys,
//! insertion sort up to 16 elements) that pushes the larger part and loops on the smaller, so at
//! most log2(n / 16) ranges wait, in a fixed 128 B array. Core's `sort_unstable` recurses, and its
//! small-sort scratch scales with the element: about 1 KB of stack per level for the offset
//! engine's 12–20 B items on the M3.
//!
//! Worst case O(n log n): after more than log2(n) unbalanced partitions (the smaller part
//! under 1/8 of its range) every remaining range is heapsorted. Equal elements may end in
//! any order (not core's order either).

/// Ranges up to this many elements are insertion-sorted.
const SMALL: usize = 16;
/// Waiting ranges (8 B each): enough for any slice below 2^20 elements (a range is only
/// split above [`SMALL`] and each waiting one is at least as long as the one sorted before
/// it); a range that finds the stack full is heapsorted.
const STACK: usize = 16;

/// Sorts `v` ascending by `key` (unstable).
pub fn sort_by_key<T: Copy, K: Ord>(v: &mut [T], mut key: impl FnMut(&T) -> K) {
    sort_by(v, |a, b| key(a) < key(b));
}

/// Sorts `v` so that no element is `is_less` than one before it (unstable). `is_less` must
/// be a strict weak order for a sorted result; any other is memory-safe and terminates.
pub fn sort_by<T: Copy>(v: &mut [T], mut is_less: impl FnMut(&T, &T) -> bool) {
    let n = v.len();
    if n <= SMALL {
        insertion(v, &mut is_less);
        return;
    }
    if u32::try_from(n).is_err() {
        heapsort(v, &mut is_less);
        return;
    }
    // Waiting ranges (start, end), and how many unbalanced partitions are still allowed.
    let mut stack = [(0u32, 0u32); STACK];
    let mut top = 0usize;
    let mut bad_left = n.ilog2();
    let (mut lo, mut hi) = (0usize, n);
    loop {
        let len = hi - lo;
        if len <= SMALL {
            insertion(&mut v[lo..hi], &mut is_less);
        } else if bad_left == 0 {
            heapsort(&mut v[lo..hi], &mut is_less);
        } else {
            let mid = lo + partition(&mut v[lo..hi], &mut is_less);
            // Left [lo, mid), pivot at mid, right [mid + 1, hi).
            let (l, r) = (mid - lo, hi - mid - 1);
            if l.min(r) < len / 8 {
                bad_left -= 1;
            }
            let (small, large) =
                if l <= r { ((lo, mid), (mid + 1, hi)) } else { ((mid + 1, hi), (lo, mid)) };
            if top < STACK {
                stack[top] = (large.0 as u32, large.1 as u32);
                top += 1;
            } else {
                heapsort(&mut v[large.0..large.1], &mut is_less);
            }
            (lo, hi) = small;
            continue;
        }
        if top == 0 {
            return;
        }
        top -= 1;
        (lo, hi) = (stack[top].0 as usize, stack[top].1 as usize);
    }
}

/// Partitions `v` (more than [`SMALL`] elements) around the median of three samples; returns
/// the pivot's final index `m`: `v[..m]` are not greater, `v[m + 1..]` not less.
fn partition<T: Copy>(v: &mut [T], is_less: &mut impl FnMut(&T, &T) -> bool) -> usize {
    let n = v.len();
    let (mut a, mut b, c) = (n / 4, n / 2, n / 4 * 3);
    if is_less(&v[b], &v[a]) {
        core::mem::swap(&mut a, &mut b);
    }
    if is_less(&v[c], &v[b]) {
        b = c;
        if is_less(&v[b], &v[a]) {
            b = a;
        }
    }
    v.swap(0, b);
    let pivot = v[0];
    // Hoare scan over v[1..]: stopping on equal keys splits runs of them evenly.
    let (mut l, mut r) = (1usize, n);
    loop {
        while l < r && is_less(&v[l], &pivot) {
            l += 1;
        }
        while l < r && is_less(&pivot, &v[r - 1]) {
            r -= 1;
        }
        if l >= r {
            break;
        }
        r -= 1;
        v.swap(l, r);
        l += 1;
    }
    // v[1..r] are not greater than the pivot, v[r..] not less: the pivot goes to r - 1.
    v.swap(0, r - 1);
    r - 1
}

fn insertion<T: Copy>(v: &mut [T], is_less: &mut impl FnMut(&T, &T) -> bool) {
    for i in 1..v.len() {
        let x = v[i];
        let mut j = i;
        while j > 0 && is_less(&x, &v[j - 1]) {
            v[j] = v[j - 1];
            j -= 1;
        }
        v[j] = x;
    }
}

fn heapsort<T: Copy>(v: &mut [T], is_less: &mut impl FnMut(&T, &T) -> bool) {
    let n = v.len();
    // Moves v[root] down the max-heap v[..end].
    let mut sift = |v: &mut [T], mut root: usize, end: usize| loop {
        let mut child = 2 * root + 1;
        if child >= end {
            return;
        }
        if child + 1 < end && is_less(&v[child], &v[child + 1]) {
            child += 1;
        }
        if !is_less(&v[root], &v[child]) {
            return;
        }
        v.swap(root, child);
        root = child;
    };
    for i in (0..n / 2).rev() {
        sift(v, i, n);
    }
    for end in (1..n).rev() {
        v.swap(0, end);
        sift(v, 0, end);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::xorshift;
    use proptest::prelude::*;

    /// Sorts a copy both ways by the key `k % modulus` (equal keys when the modulus is
    /// small) and checks: same multiset (the full pairs sorted), keys ascending.
    fn check(v: &[(u32, u32)], modulus: u32) {
        let mut ours = v.to_vec();
        sort_by_key(&mut ours, |p| p.0 % modulus);
        let mut core_ = v.to_vec();
        core_.sort_unstable_by_key(|p| p.0 % modulus);
        let keys = |s: &[(u32, u32)]| s.iter().map(|p| p.0 % modulus).collect::<Vec<_>>();
        assert_eq!(keys(&ours), keys(&core_));
        let (mut a, mut b) = (ours.clone(), v.to_vec());
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "not a permutation");
    }

    /// Tags each key with its position, so a permutation check sees every element.
    fn tagged(keys: impl IntoIterator<Item = u32>) -> Vec<(u32, u32)> {
        keys.into_iter().enumerate().map(|(i, k)| (k, i as u32)).collect()
    }

    #[test]
    fn patterns() {
        let mut rng = xorshift(0x9e37_79b9_7f4a_7c15);
        for n in (0..70).chain([100, 127, 128, 129, 500, 1000, 4097, 20_000]) {
            let n32 = n as u32;
            let inputs: Vec<Vec<u32>> = vec![
                (0..n32).collect(),
                (0..n32).rev().collect(),
                vec![7; n],
                (0..n32).map(|i| i.min(n32 - 1 - i)).collect(),
                (0..n32).map(|i| i.max(n32 - 1 - i)).collect(),
                (0..n32).map(|i| i % 2).collect(),
                (0..n32).map(|i| if i == n32 / 2 { 0 } else { i }).collect(),
                (0..n32).map(|i| (i * 7919) % (n32 + 1)).collect(),
                (0..n).map(|_| rng() as u32).collect(),
                (0..n).map(|_| (rng() % 5) as u32).collect(),
            ];
            for keys in inputs {
                for m in [u32::MAX, 3] {
                    check(&tagged(keys.iter().copied()), m);
                }
            }
        }
    }

    /// Median-of-three killers and sorted runs must not blow up: the heapsort fallback
    /// bounds the comparisons.
    #[test]
    fn bounded_comparisons() {
        for n in [1000usize, 30_000] {
            let n32 = n as u32;
            let inputs: Vec<Vec<u32>> = vec![
                (0..n32).collect(),
                (0..n32).rev().collect(),
                (0..n32).map(|i| i.min(n32 - 1 - i)).collect(),
                (0..n32).map(|i| (i % 2) * n32 + i / 2).collect(),
                (0..n32).map(|i| if i % 2 == 0 { i } else { n32 - i }).collect(),
            ];
            for keys in inputs {
                let mut v = keys.clone();
                let mut cmps = 0u64;
                sort_by(&mut v, |a, b| {
                    cmps += 1;
                    a < b
                });
                assert!(v.windows(2).all(|w| w[0] <= w[1]));
                let bound = 8 * n as u64 * u64::from(n.ilog2());
                assert!(cmps < bound, "n {n}: {cmps} comparisons");
            }
        }
    }

    /// Beyond 2^20 elements the waiting ranges can fill the stack: the fallback sorts too.
    #[test]
    fn deep_slices() {
        let mut rng = xorshift(777);
        let v: Vec<(u32, u32)> = tagged((0..1 << 21).map(|_| rng() as u32));
        check(&v, u32::MAX);
    }

    /// An inconsistent comparison neither panics nor loses elements.
    #[test]
    fn inconsistent_order_is_safe() {
        let mut rng = xorshift(12345);
        let mut v: Vec<u32> = (0..3000).collect();
        sort_by(&mut v, |_, _| rng() % 2 == 0);
        v.sort_unstable();
        assert!(v.iter().enumerate().all(|(i, &x)| x == i as u32));
    }

    proptest! {
        #[test]
        fn random(keys in proptest::collection::vec(any::<u32>(), 0..600), m in 1u32..50) {
            check(&tagged(keys.iter().copied()), u32::MAX);
            check(&tagged(keys), m);
        }
    }
}
