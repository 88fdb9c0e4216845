//! The pressure solver over MPI ranks on a model problem: the multilinear-element Laplacian
//! on n^D cells (p = 0 on the walls), solved to 1e-8 by the multigrid-preconditioned
//! conjugate gradient with its rows cut into slabs along the last axis, one a rank
//! (`pmpm::linalg::spread`). Each rank fills only the rows of its slab and of the node layer
//! beside it, as the projection's assembly would. Prints, on rank 0, the rows, levels,
//! iterations, the seconds of the first solve (the multigrid set up) and of a solve
//! that reuses it (the mean of `REPEATS`), and each rank's peak
//! resident memory.
//!
//!   cargo build --profile quick -p pmpm --features mpi --example poisson_ranks
//!   mpirun -n R target/quick/examples/poisson_ranks DIM N [THREADS] [--check]
//!
//! With `--check` each rank also solves the whole system on its own, as one process does,
//! and the run fails (exit status 1) unless the ranks took that solve's iterations within 2
//! and their rows agree with it within 1e-6 of its largest value (what `.ci/run` runs).
//!
//! BENCHMARKS.md, "The pressure solve over MPI ranks", has the figures.

use pmpm::comm::{Comm, Mpi};
use pmpm::linalg::{
    EllMatrix, GridLayout, LinearSolver, Multigrid, Partition, Pcg, SolveParams, System,
};
use std::sync::Arc;
use std::time::Instant;

const REPEATS: usize = 5;
const PAD: usize = 2;

fn main() {
    let check = std::env::args().any(|a| a == "--check");
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter(|a| a != "--check")
        .map(|a| a.parse().unwrap_or(0))
        .collect();
    let (dim, n) = match args[..] {
        [dim @ (2 | 3), n, ..] if n >= 4 => (dim, n),
        _ => {
            eprintln!("usage: mpirun -n R poisson_ranks DIM(2|3) N(>=4) [THREADS] [--check]");
            std::process::exit(2);
        }
    };
    let threads = args.get(2).copied().unwrap_or(1).max(1);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .expect("the thread pool starts once");
    let comm: Arc<dyn Comm> = match Mpi::init() {
        Some(Ok(m)) => Arc::new(m),
        _ => {
            eprintln!("MPI did not start");
            std::process::exit(1);
        }
    };
    let nodes = n + 1 + 2 * PAD;
    let size = comm.size();
    let cuts: Vec<usize> = (0..=size).map(|r| r * nodes / size).collect();
    let rank = comm.rank();
    let (lo, hi) = (cuts[rank], cuts[rank + 1]);
    let (a, layout) = laplacian(dim, n, lo.saturating_sub(1)..hi + 1);
    let partition = Partition {
        comm: comm.clone(),
        cuts,
    };
    // a smooth right-hand side with every scale in it: the same on any rank count
    let b: Vec<f64> = layout
        .index
        .iter()
        .map(|i| {
            (0..dim)
                .map(|d| (0.37 * i[d] as f64 * (d + 1) as f64).sin())
                .sum()
        })
        .collect();
    let system = System {
        matrix: &a,
        layout: &layout,
        singular: false,
        partition: Some(&partition),
    };
    let params = SolveParams {
        tolerance: 1e-8,
        max_iterations: 500,
    };
    let mut solver = LinearSolver::Pcg(Pcg::new(Box::<Multigrid>::default()));
    let mut x = vec![0.0; a.n];
    let mut iterations = 0;
    // the first solve sets the multigrid up; the others reuse it (as a step's further passes)
    let mut seconds = [0.0; 2];
    for repeat in 0..=REPEATS {
        x.fill(0.0);
        let start = Instant::now();
        let solved = if repeat == 0 {
            solver.solve(&system, &b, &mut x, params)
        } else {
            solver.solve_again(&system, &b, &mut x, params)
        };
        match solved {
            Ok(s) => iterations = s.iterations,
            Err(e) => {
                eprintln!("rank {rank}: {e}");
                std::process::exit(1);
            }
        }
        let t = start.elapsed().as_secs_f64();
        seconds[usize::from(repeat > 0)] += if repeat == 0 { t } else { t / REPEATS as f64 };
    }
    comm.max(&mut seconds);
    let mut memory = vec![0.0; size];
    memory[rank] = pmpm::run::peak_memory().unwrap_or(0) as f64;
    comm.sum(&mut memory);
    if check && !agrees_with_one_process(&*comm, (&layout, &b, &x), (dim, n, lo..hi), iterations) {
        std::process::exit(1);
    }
    if rank == 0 {
        let mb: Vec<String> = memory.iter().map(|m| format!("{:.0}", m / 1e6)).collect();
        println!(
            "{dim}D {n}^{dim} cells, {} rows, {size} ranks x {threads} threads: {iterations} \
             iterations, {:.4} s set-up and solve, {:.4} s a solve, peak MB per rank {}",
            a.n,
            seconds[0],
            seconds[1],
            mb.join(" ")
        );
    }
}

/// Whether `x` (this rank's rows, `layers` along the last axis) and the ranks' `iterations`
/// agree with the whole system solved on this process alone: the iterations within 2, every
/// row within 1e-6 of the largest value. Rank 0 says how far they are.
fn agrees_with_one_process(
    comm: &dyn Comm,
    (layout, b, x): (&GridLayout, &[f64], &[f64]),
    (dim, n, layers): (usize, usize, std::ops::Range<usize>),
    iterations: usize,
) -> bool {
    let (a, _) = laplacian(dim, n, 0..usize::MAX);
    let system = System {
        matrix: &a,
        layout,
        singular: false,
        partition: None,
    };
    let params = SolveParams {
        tolerance: 1e-8,
        max_iterations: 500,
    };
    let mut one = vec![0.0; a.n];
    let mut solver = LinearSolver::Pcg(Pcg::new(Box::<Multigrid>::default()));
    let Ok(stats) = solver.solve(&system, b, &mut one, params) else {
        return false;
    };
    let scale = one.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let own = |r: usize| layers.contains(&(layout.index[r][dim - 1] as usize));
    let mut err = [(0..a.n)
        .filter(|&r| own(r))
        .fold(0.0f64, |m, r| m.max((x[r] - one[r]).abs()))];
    comm.max(&mut err);
    let ok = iterations.abs_diff(stats.iterations) <= 2 && err[0] <= 1e-6 * scale;
    if comm.rank() == 0 {
        println!(
            "check: {} iterations on one process, {iterations} over {} ranks; rows differ by at \
             most {:.1e} of the largest value: {}",
            stats.iterations,
            comm.size(),
            err[0] / scale,
            if ok { "agree" } else { "DISAGREE" }
        );
    }
    ok
}

/// The Q1 Laplacian's rows on the node layers `fill` along the last axis (the rest left
/// empty: the rows another rank computes), every row numbered in node order. The entry for a
/// neighbour at offset o is sum_d K(o_d) prod_{e != d} M(o_e), with the 1D stiffness
/// K = (-1, 2, -1) and mass M = (1, 4, 1) / 6.
fn laplacian(dim: usize, n: usize, fill: std::ops::Range<usize>) -> (EllMatrix, GridLayout) {
    let m = n - 1;
    let rows = m.pow(dim as u32);
    let width = 3usize.pow(dim as u32);
    let (k, mass) = ([-1.0, 2.0, -1.0], [1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0]);
    let at = |r: usize, d: usize| r / m.pow(d as u32) % m;
    let mut a = EllMatrix::default();
    a.reshape(rows, width);
    for r in 0..rows {
        let mine = fill.contains(&(PAD + 1 + at(r, dim - 1)));
        for s in 0..width {
            let o = |d: usize| s / 3usize.pow(d as u32) % 3;
            let mut j = Some(0);
            for d in 0..dim {
                let c = (at(r, d) + o(d)).checked_sub(1).filter(|&c| c < m);
                j = j.zip(c).map(|(j, c)| j + c * m.pow(d as u32));
            }
            let v: f64 = (0..dim)
                .map(|d| {
                    k[o(d)]
                        * (0..dim)
                            .filter(|&e| e != d)
                            .map(|e| mass[o(e)])
                            .product::<f64>()
                })
                .sum();
            let (c, v) = match j {
                Some(j) if mine => (j, v),
                _ => (r, 0.0),
            };
            a.cols[r * width + s] = c as u32;
            a.vals[r * width + s] = v;
        }
    }
    let mut layout = GridLayout {
        dim,
        reach: 1,
        ..GridLayout::default()
    };
    for d in 0..dim {
        layout.nodes[d] = n + 1 + 2 * PAD;
        layout.offset[d] = PAD;
        layout.cells[d] = n;
    }
    layout.index = (0..rows)
        .map(|r| {
            std::array::from_fn(|d| {
                if d < dim {
                    (PAD + 1 + at(r, d)) as u32
                } else {
                    0
                }
            })
        })
        .collect();
    (a, layout)
}
