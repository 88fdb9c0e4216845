//! Inflow and outflow: particles that cross an outflow face leave the run and are counted,
//! an inflow emits the mass its patch's velocity gives, and series.csv's mass balance closes
//! to round-off.

use crate::common;

use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::Path;

/// The columns of series.csv by name, one vector per column.
fn series(dir: &Path) -> std::collections::HashMap<String, Vec<f64>> {
    let t = pmpm_cli::table::Table::read(&dir.join("series.csv")).unwrap();
    t.header
        .iter()
        .enumerate()
        .map(|(k, h)| (h.clone(), t.rows.iter().map(|r| r[k]).collect()))
        .collect()
}

fn run(name: &str, text: &str) -> std::path::PathBuf {
    let dir = scratch_dir(name);
    let deck = dir.join("deck.toml");
    std::fs::write(&deck, text).unwrap();
    let out = dir.join("out");
    let o = pmpm(&[
        "run",
        deck.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-q",
    ]);
    assert!(
        o.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// A column of water pushed along x by a tilted gravity runs out through the face x_max:
/// the run goes on without it, and series.csv counts it out with the balance at round-off.
#[test]
fn an_outflow_face_lets_the_water_out_and_counts_it() {
    for scheme in ["projection", "explicit"] {
        let text = SMALL_2D
            .replace("\"explicit\"", &format!("\"{scheme}\""))
            .replace("end_time = 0.05", "end_time = 0.3")
            .replace("gravity = [0.0, -9.81]", "gravity = [5.0, -9.81]")
            .replace("x_max = \"slip\"", "x_max = \"outflow\"")
            // a slip floor, as the estimate below assumes: on the no-slip floor the bottom
            // rows stay behind and half the particles are left at 0.3 s (48 of 100 with
            // density_correction = "positions", 50 with "particles"), at the bound
            .replace("y_min = \"no_slip\"", "y_min = \"slip\"")
            .replace("interval = 0.01", "interval = 0.05")
            .replace(
                "min = [0.0, 0.0], max = [0.1, 0.1]",
                "min = [0.2, 0.0], max = [0.3, 0.1]",
            );
        let out = run(&format!("outflow-{scheme}"), &text);
        let s = series(&out);
        let (n, m_out, mass) = (&s["particles"], &s["mass_out"], &s["mass"]);
        let last = n.len() - 1;
        // 0.1 m of water 0.1 to 0.2 m from the face, at 5 m/s2 along x: most of it is out
        // by t = 0.3 s (it would take 0.28 s to slide 0.2 m; the projection leaves 37 of 100)
        assert!(
            n[last] < 0.5 * n[0],
            "{scheme}: {} of {} particles left",
            n[last],
            n[0]
        );
        assert!(
            m_out[last] > 0.5 * mass[0],
            "{scheme}: {} kg out",
            m_out[last]
        );
        for (k, b) in s["mass_balance"].iter().enumerate() {
            assert!(b.abs() < 1e-12, "{scheme}: frame {k}: mass balance {b}");
        }
        // what is left plus what went out is what there was, row by row
        for k in 0..=last {
            let err = (mass[k] + m_out[k] - mass[0]).abs();
            assert!(err < 1e-12 * mass[0], "{scheme}: frame {k}: {err}");
        }
    }
}

/// Water enters a channel through a patch 0.06 m high at 0.5 m/s over a slip floor: the
/// mass that entered by each frame is rho u d t to within one layer of the lattice, and it
/// spreads along the floor; with either density correction (neither moves the particles in
/// the inflow's buffer).
#[test]
fn an_inflow_emits_the_flux_of_its_patch() {
    for correction in ["positions", "particles"] {
        let text = SMALL_2D
            .replace("\"explicit\"", "\"projection\"")
            .replace("end_time = 0.05", "end_time = 0.3")
            .replace("y_min = \"no_slip\"", "y_min = \"slip\"")
            .replace("interval = 0.01", "interval = 0.05")
            .replace("min = [0.0, 0.0], max = [0.1, 0.1]", "min = [0.0, 0.0], max = [0.4, 0.02]")
            + "\n[[inflows]]\nmaterial = \"water\"\nface = \"x_min\"\nmin = [0.0, 0.0]\nmax = [0.0, 0.06]\nvelocity = [0.5, 0.0]\n"
            + &format!("\n[pressure]\ndensity_correction = \"{correction}\"\n");
        let out = run(&format!("inflow-{correction}"), &text);
        let s = series(&out);
        let (rho, u, depth, spacing) = (1000.0, 0.5, 0.06, 0.01);
        let layer = rho * depth * spacing;
        for (k, (&t, &m_in)) in s["time"].iter().zip(&s["mass_in"]).enumerate() {
            let expect = rho * u * depth * t;
            assert!(
                (m_in - expect).abs() <= layer + 1e-9,
                "{correction}: frame {k}, t = {t}: {m_in} kg entered, rho u d t = {expect} (one layer {layer})"
            );
            assert!(s["mass_balance"][k].abs() < 1e-12);
        }
        assert!(s["mass_in"].last().unwrap() > &(0.5 * rho * u * depth * 0.3));
    }
}
