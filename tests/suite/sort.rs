//! The periodic sort of the particles by cell: it changes where a particle is stored, not what
//! happens to it, and the output still lists particles by id.

use crate::common;

use common::{deck, drive, in_pool, pmpm, scratch_dir, SMALL_2D};
use pmpm::scheme::Simulation;

/// The same dam break (projection, 60 steps) sorted every step and never sorted: every
/// particle ends at the same place. Sorting changes the order of the sums in P2G and in the
/// pressure assembly, so the two runs agree to round-off, not bit for bit; 1e-9 h after 60
/// steps leaves round-off room a thousand times over while catching any particle whose fields
/// were not moved with it (that would be an error of order h).
#[test]
fn sorting_moves_particles_without_changing_them() {
    let run = |interval: usize| {
        let text = SMALL_2D
            .replace("\"explicit\"", "\"projection\"")
            .replace("end_time = 0.05", "end_time = 2.0")
            .replace(
                "transfer = \"apic\"",
                &format!("transfer = \"apic\"\nsort_interval = {interval}"),
            );
        let d = deck(&text);
        in_pool(2, || {
            let mut sim = Simulation::<2>::new(&d).unwrap();
            drive(&d, &mut sim, |sim, _| sim.steps < 60);
            sim
        })
    };
    let (sorted, unsorted) = (run(1), run(0));
    let h = sorted.grid.geo.h;
    // the unsorted run keeps the creation order, the sorted one is in cell order
    assert!(unsorted
        .particles
        .id
        .iter()
        .enumerate()
        .all(|(p, &id)| p as u32 == id));
    let cells: Vec<usize> = sorted
        .particles
        .x
        .iter()
        .map(|x| sorted.grid.geo.cell_of(x))
        .collect();
    let mut ids = sorted.particles.id.clone();
    ids.sort_unstable();
    assert!(
        ids.iter().enumerate().all(|(k, &id)| k as u32 == id),
        "ids are a permutation"
    );
    assert_ne!(
        sorted.particles.id, unsorted.particles.id,
        "the flow has mixed the particles"
    );
    // sorted at the start of the last step: the cells were in order before it moved them
    let out_of_order = cells.windows(2).filter(|w| w[0] > w[1]).count();
    assert!(
        out_of_order * 10 < cells.len(),
        "{out_of_order} of {}",
        cells.len()
    );
    let (a, b) = (&sorted.particles, &unsorted.particles);
    let worst = a
        .by_id(&a.x)
        .iter()
        .zip(&b.by_id(&b.x))
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max);
    println!(
        "largest position difference, sorted against unsorted: {:.2e} h",
        worst / h
    );
    assert!(worst <= 1e-9 * h, "{:.2e} h", worst / h);
    let dp = a
        .by_id(&a.pressure)
        .iter()
        .zip(&b.by_id(&b.pressure))
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max);
    let pmax = b.pressure.iter().fold(0.0f64, |m, p| m.max(p.abs()));
    assert!(dp <= 1e-8 * pmax, "pressure differs by {dp:e} of {pmax:e}");
}

/// With a sort every step the frames still list the particles by id, 0 to n - 1.
#[test]
fn frames_list_particles_by_id() {
    let dir = scratch_dir("sorted-frames");
    let deck_path = dir.join("deck.toml");
    let text = SMALL_2D.replace(
        "transfer = \"apic\"",
        "transfer = \"apic\"\nsort_interval = 1",
    );
    std::fs::write(&deck_path, text).unwrap();
    let out = dir.join("out");
    let o = pmpm(&[
        "--threads",
        "2",
        "run",
        deck_path.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let last = std::fs::read_dir(out.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .max()
        .unwrap();
    let frame = pmpm_cli::table::Table::read(&last).unwrap();
    assert_eq!(frame.header[0], "id");
    let ids: Vec<usize> = frame.rows.iter().map(|r| r[0] as usize).collect();
    assert_eq!(ids.len(), 100, "5 x 5 cells, 2 x 2 particles each");
    assert!(ids.iter().enumerate().all(|(k, &id)| k == id), "{last:?}");
}
