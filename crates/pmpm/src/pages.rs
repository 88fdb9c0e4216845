//! Node arrays that hold memory only where the material is: the grid's sparsity by pages.
//!
//! The grid numbers every node of the box, and a tank is mostly air. A node array is
//! allocated zeroed in virtual memory ([`zeroed`]): the operating system gives it a physical
//! page the first time the page is written, and a page never written reads as zeros from
//! the kernel's shared zero page. The step writes a node only where its value changes
//! ([`store`], [`reset`]), so an empty node stays on an uncommitted page and the resident
//! memory follows the nodes the material has reached, a page (4 KiB: 512 `f64` nodes along
//! axis 0) at a time. This is the virtual-memory form of a block-sparse grid (SPGrid:
//! Setaluri, Aanjaneya, Bauer & Sifakis 2014), with the page table as the block table; the
//! loops still visit every node, and reading an uncommitted node is a read of the zero page.
//!
//! Two settings of the C library and the kernel would commit whole arrays, and both are set
//! here: glibc serves a large `calloc` from fresh `mmap` pages only above its mmap threshold,
//! which it raises as large blocks are freed (then `calloc` clears heap memory and commits
//! it), so the threshold is fixed at its default; and transparent huge pages (where the
//! system enables them for every mapping) would commit 2 MiB for one written node, so the
//! arrays are marked to take small pages.

use bytemuck::{NoUninit, Zeroable};

/// A node array of `n` zeros whose pages are committed only where written.
pub fn zeroed<T: Zeroable>(n: usize) -> Vec<T> {
    fix_mmap_threshold();
    let v = bytemuck::zeroed_vec::<T>(n);
    small_pages(&v);
    v
}

/// `v` as a node array of `n` zeros where it does not hold `n` values yet (the values it
/// holds are kept): [`zeroed`] in place of `Vec::resize`, which would write every zero.
pub fn fit<T: Zeroable>(v: &mut Vec<T>, n: usize) {
    if v.len() != n {
        *v = zeroed(n);
    }
}

/// `*x = value`, written only where it changes `x`'s bytes (so a node that stays zero stays
/// on an uncommitted page). The same bits as the plain store: the bytes are compared, so 0
/// and -0 are told apart.
#[inline]
pub fn store<T: NoUninit>(x: &mut T, value: T) {
    if bytemuck::bytes_of(x) != bytemuck::bytes_of(&value) {
        *x = value;
    }
}

/// `dst` as a copy of `src`, writing only the values that differ ([`fit`] where `dst` does
/// not hold as many values yet): `clone_from` in place of a copy that commits every page.
pub fn copy<T: NoUninit + Zeroable + Send + Sync>(dst: &mut Vec<T>, src: &[T]) {
    use rayon::prelude::*;
    fit(dst, src.len());
    dst.par_iter_mut()
        .zip(src.par_iter())
        .for_each(|(d, &s)| store(d, s));
}

/// Sets every value of `v` to zero, writing only the values that are not zero already. A
/// run of values is first tested whole (its words or-ed, a vectorised loop): a run of zeros
/// (the air, read from the kernel's zero page) costs a fraction of a per-value test.
pub fn reset<T: NoUninit + Zeroable + Send + Sync>(v: &mut [T]) {
    use rayon::prelude::*;
    v.par_chunks_mut(RUN).for_each(|run| {
        if !zero_bytes(bytemuck::cast_slice::<T, u8>(run)) {
            run.iter_mut().for_each(|x| store(x, T::zeroed()));
        }
    });
}

/// The values [`reset`] reads at a time: a page's worth of `f64`.
const RUN: usize = 512;

/// Whether every byte is zero: the words or-ed together without an early exit, a loop the
/// compiler turns into vector instructions.
fn zero_bytes(bytes: &[u8]) -> bool {
    let (head, words, tail) = bytemuck::pod_align_to::<u8, u64>(bytes);
    let loose = head.iter().chain(tail).fold(0u8, |a, &b| a | b);
    loose == 0 && words.iter().fold(0u64, |a, &w| a | w) == 0
}

/// Fixes glibc's mmap threshold at its default (128 KiB), once: large blocks then always come
/// from `mmap`, whose pages are zero until written, and `calloc` does not clear them.
fn fix_mmap_threshold() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        static ONCE: std::sync::Once = std::sync::Once::new();
        ONCE.call_once(|| {
            // SAFETY: mallopt only sets an allocator parameter; any value is valid.
            unsafe {
                libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
            }
        });
    }
}

/// Asks the kernel to back `v`'s whole pages with small pages, so that one written node
/// commits 4 KiB and not a 2 MiB huge page.
fn small_pages<T>(v: &[T]) {
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let start = v.as_ptr() as usize;
        let end = start + std::mem::size_of_val(v);
        let first = start.next_multiple_of(PAGE);
        let last = end / PAGE * PAGE;
        // (smaller arrays come from the heap, a mapping the allocator shares)
        if last > first && end - start >= 128 * 1024 {
            // SAFETY: the range lies inside `v`'s allocation, which this process owns;
            // MADV_NOHUGEPAGE changes no data, only how later faults are backed.
            unsafe {
                libc::madvise(
                    first as *mut libc::c_void,
                    last - first,
                    libc::MADV_NOHUGEPAGE,
                );
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = v;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn store_tells_signed_zeros_apart_and_skips_equal_values() {
        let mut x = 0.0f64;
        store(&mut x, -0.0);
        assert!(x.is_sign_negative());
        store(&mut x, 1.5);
        assert_eq!(x, 1.5);
        let mut v: Vec<f64> = zeroed(10_000);
        v[3] = 2.0;
        reset(&mut v);
        assert!(v.iter().all(|x| x.to_bits() == 0));
        let mut w: Vec<f64> = Vec::new();
        fit(&mut w, 5);
        w[1] = 1.0;
        fit(&mut w, 5);
        assert_eq!(w, [0.0, 1.0, 0.0, 0.0, 0.0]);
    }

    /// Resident bytes of the mapping that holds `v` (/proc/self/smaps; the kernel's shared
    /// zero page, which a read of an unwritten page maps, is not counted).
    #[cfg(target_os = "linux")]
    fn resident_bytes(v: &[f64]) -> usize {
        // (the middle: the array's first and last part pages share mappings with neighbours)
        let at = v.as_ptr() as usize + std::mem::size_of_val(v) / 2;
        let smaps = std::fs::read_to_string("/proc/self/smaps").unwrap();
        let mut inside = false;
        for line in smaps.lines() {
            let range = line.split_whitespace().next().unwrap_or("");
            if let Some((lo, hi)) = range.split_once('-') {
                if let (Ok(lo), Ok(hi)) =
                    (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
                {
                    inside = lo <= at && at < hi;
                    continue;
                }
            }
            if let Some(kb) = line.strip_prefix("Rss:").filter(|_| inside) {
                return kb
                    .trim()
                    .trim_end_matches("kB")
                    .trim()
                    .parse::<usize>()
                    .unwrap()
                    * 1024;
            }
        }
        panic!("no mapping holds the array")
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_node_array_commits_only_the_pages_written() {
        // 64 MiB of nodes: zeroed, stored zeros, a reset and a copy leave the pages
        // uncommitted (under 5 %: the mapping may hold a neighbour); values written commit them
        let n = 1 << 23;
        let bytes = n * 8;
        let mut v: Vec<f64> = zeroed(n);
        assert!(v.iter().all(|&x| x == 0.0));
        for x in v.iter_mut() {
            store(x, 0.0);
        }
        reset(&mut v);
        assert!(resident_bytes(&v) < bytes / 20, "{}", resident_bytes(&v));
        let mut w: Vec<f64> = Vec::new();
        copy(&mut w, &v);
        assert!(resident_bytes(&w) < bytes / 20, "{}", resident_bytes(&w));
        v.iter_mut().for_each(|x| store(x, 1.0));
        assert!(resident_bytes(&v) >= bytes * 19 / 20);
    }
}
