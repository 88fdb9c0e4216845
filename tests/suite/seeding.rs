//! The particles at t = 0 hold density times the volume of the shapes they fill, wherever the
//! shapes' faces fall between the lattice's rows, and `pmpm check` says when the lattice and
//! the shape differ by more than 0.5 %.

use crate::common;
use common::{pmpm, scratch_dir};

/// A 2D projection deck in a tank of `size` at h = 4 cm with the given bodies and rigid bodies.
fn tank(size: &str, bodies: &str) -> String {
    format!(
        r#"
[simulation]
dimension = 2
end_time = 0.1

[grid]
size = {size}
cell_size = 0.04

[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3
{bodies}
"#
    )
}

/// The mass and the volume of the particles of each body, and the bodies' seeding report.
fn seeded(text: &str) -> (f64, f64, Vec<pmpm::seed::Seeding>) {
    let d = common::deck(text);
    let geo = pmpm::build::grid_geometry::<2>(&d);
    let (ps, report) = pmpm::build::seeded::<2>(&d, &geo).unwrap();
    (ps.mass.iter().sum(), ps.volume0.iter().sum(), report)
}

/// 1.228 x 0.55 m of water at h = 4 cm (lattice spacing 2 cm): the lattice takes the rows whose
/// centres lie on or inside the faces, 1.22 x 0.56 m, 1.15 % more than the box. Before, the
/// mass was that of the lattice (+1.15 %); now it is rho times the box's area to round-off.
#[test]
fn a_box_between_lattice_rows_holds_its_own_mass() {
    let text = tank(
        "[3.24, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [1.228, 0.55] }
particles_per_cell = 2
"#,
    );
    let (mass, volume, report) = seeded(&text);
    let exact = 1.228 * 0.55;
    assert!((mass / (1000.0 * exact) - 1.0).abs() < 1e-12, "mass {mass}");
    assert!((volume / exact - 1.0).abs() < 1e-12, "volume {volume}");
    assert_eq!(report[0].particles, 61 * 28);
    assert!((report[0].excess() - 0.0115).abs() < 1e-3, "{report:?}");
    assert!((report[0].seeded / exact - 1.0).abs() < 1e-12, "{report:?}");
}

/// Water around a rigid block whose faces lie between the lattice's rows: the rigid body's
/// points get no particle, and the rest keep the lattice's volume (the body's own faces are on
/// its rows, so nothing is scaled): the cut cells take the open part of a cell at the block's
/// face as the cell beyond it, which keeps the water at rest
/// (`rigid::water_stays_at_rest_under_a_box_held_at_any_height`).
#[test]
fn water_around_a_rigid_block_keeps_its_lattice_volume() {
    let around = tank(
        "[1.0, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [1.0, 0.5] }
particles_per_cell = 2

[[rigid_bodies]]
name = "block"
shape = { type = "box", min = [0.413, 0.0], max = [0.623, 0.33] }
"#,
    );
    let (mass, volume, report) = seeded(&around);
    let s2 = 0.02 * 0.02;
    // the block holds the lattice points strictly inside it, x = 0.43 .. 0.61 and y = 0.01 ..
    // 0.31: 10 x 16
    assert_eq!(report[0].particles, 50 * 25 - 10 * 16, "{report:?}");
    assert!((volume / (report[0].particles as f64 * s2) - 1.0).abs() < 1e-12);
    assert!((mass / (1000.0 * volume) - 1.0).abs() < 1e-12);
}

/// Shapes without a closed form for the part that is filled, integrated on the lattice: a
/// slope's ground (a half-space cut off by the grid) and two boxes joined; each holds its exact
/// area within 0.1 % (measured: 1e-15 and -0.017 %; before, the lattice's: +0.13 % and
/// -0.16 %). A disc, in closed form, holds pi r^2 to round-off.
#[test]
fn shapes_without_a_closed_form_hold_their_own_mass() {
    // the ground below y = 0.305 - 0.3 x over the tank's metre: 0.155 m2
    let slope = tank(
        "[1.0, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "half_space", point = [0.0, 0.305], normal = [0.3, 1.0] }
particles_per_cell = 2
"#,
    );
    let (mass, _, report) = seeded(&slope);
    assert!(
        (mass / 155.0 - 1.0).abs() < 1e-3,
        "slope: mass {mass}, {report:?}"
    );
    // two boxes joined, their faces off the rows: 0.513 x 0.3 and 0.264 x 0.147 beyond it
    let joined = tank(
        "[1.0, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "union", shapes = [
    { type = "box", min = [0.0, 0.0], max = [0.513, 0.3] },
    { type = "box", min = [0.2, 0.0], max = [0.777, 0.147] },
] }
particles_per_cell = 2
"#,
    );
    let (mass, _, report) = seeded(&joined);
    let exact = 1000.0 * (0.513 * 0.3 + 0.264 * 0.147);
    assert!(
        (mass / exact - 1.0).abs() < 1e-3,
        "joined: mass {mass} against {exact}, {report:?}"
    );
    // a disc within the grid: its area in closed form, pi r^2
    let disc = tank(
        "[1.0, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "sphere", center = [0.5, 0.5], radius = 0.137 }
particles_per_cell = 2
"#,
    );
    let (mass, _, _) = seeded(&disc);
    let exact = 1000.0 * std::f64::consts::PI * 0.137 * 0.137;
    assert!(
        (mass / exact - 1.0).abs() < 1e-12,
        "disc: mass {mass} against {exact}"
    );
}

/// What `pmpm check` prints (stdout, then stderr) for the tank with one box of water from the
/// origin to `max`; it must succeed.
fn check_box(dir: &std::path::Path, name: &str, max: &str) -> String {
    let deck = dir.join(format!("{name}.toml"));
    let body = format!(
        "[[bodies]]\nmaterial = \"water\"\nshape = {{ type = \"box\", min = [0.0, 0.0], max = {max} }}\nparticles_per_cell = 2\n"
    );
    std::fs::write(&deck, tank("[3.24, 1.0]", &body)).unwrap();
    let o = pmpm(&["check", deck.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{text}");
    text
}

/// `check` prints the shape's volume and warns where the lattice is off by more than 0.5 %,
/// and says nothing where it fits.
#[test]
fn check_says_when_the_lattice_differs_from_the_shape() {
    let dir = scratch_dir("seeding-check");
    let text = check_box(&dir, "off", "[1.228, 0.55]");
    assert!(text.contains("volume 6.754000e-1"), "{text}");
    assert!(text.contains("+1.15 % of its shape's"), "{text}");
    let text = check_box(&dir, "fits", "[1.22, 0.56]");
    assert!(!text.contains("of its shape's"), "{text}");
}

/// A 3.22 m tank at h = 4 cm (80.5 cells) used to be refused; the grid now covers it with 81
/// cells, `check` and `run` say where its x_max wall stands, and the run's deck holds the size
/// run. 3.22 m and 1 m share no cell coarser than 2 cm, which would cost 4 times the particles.
#[test]
fn a_tank_that_is_not_a_whole_number_of_cells_is_covered_and_said() {
    let dir = scratch_dir("tank-rounded");
    let deck = dir.join("tank.toml");
    let text = tank(
        "[3.22, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [1.228, 0.55] }
particles_per_cell = 2

[output]
interval = 0.05
"#,
    );
    std::fs::write(&deck, text.replace("end_time = 0.1", "end_time = 0.05")).unwrap();
    let said = "grid.size[0] = 3.22 m is 80.5000 cells of 0.04 m: the grid takes 81 cells, 3.24 m, and its x_max face stands 2.0000e-2 m beyond the deck's 3.22 m";
    let o = pmpm(&["check", deck.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("81 x 25 cells of h = 0.04 m"), "{text}");
    assert!(text.contains(said), "{text}");
    let out = dir.join("out");
    let o = pmpm(&["run", deck.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{text}");
    assert!(text.contains(said), "{text}");
    let run: toml::Table =
        toml::from_str(&std::fs::read_to_string(out.join("run.toml")).unwrap()).unwrap();
    let size = run["grid"]["size"].as_array().unwrap();
    assert!(
        (size[0].as_float().unwrap() - 3.24).abs() < 1e-12,
        "{size:?}"
    );
    // the deck as the user wrote it resumes the run (its size rounded as before)
    let longer = dir.join("longer.toml");
    std::fs::write(
        &longer,
        std::fs::read_to_string(&deck)
            .unwrap()
            .replace("end_time = 0.05", "end_time = 0.1"),
    )
    .unwrap();
    let o = pmpm(&[
        "run",
        longer.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "-q",
        "--resume",
        out.join("checkpoint.bin").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A rank of a distributed run builds only its part of the particles: two parts (here the
/// particles left and right of x = 0.5 m) hold between them every particle of the whole
/// seeding, each with the id, place, mass, volume and hydrostatic pressure it has there: the
/// pressure is taken from the top of the whole body, not of the part.
#[test]
fn parts_of_the_seeding_are_the_whole_seeding_shared_out() {
    let text = tank(
        "[2.0, 1.0]",
        r#"
[[bodies]]
material = "water"
shape = { type = "polygon", vertices = [[0.0, 0.0], [1.2, 0.0], [0.0, 0.8]] }
particles_per_cell = 2
stress = "hydrostatic"
"#,
    );
    let d = common::deck(&text);
    let geo = pmpm::build::grid_geometry::<2>(&d);
    let whole = pmpm::build::particles::<2>(&d, &geo).unwrap();
    let left = pmpm::build::part::<2>(&d, &geo, &mut |_, x| x[0] < 0.5).unwrap();
    let right = pmpm::build::part::<2>(&d, &geo, &mut |_, x| x[0] >= 0.5).unwrap();
    assert!(!left.x.is_empty() && !right.x.is_empty());
    assert_eq!(left.len() + right.len(), whole.len());
    // the right part's top is 0.33 m below the body's: its own would lower p by rho g 0.33 m
    for part in [&left, &right] {
        for p in 0..part.len() {
            let w = part.id[p] as usize;
            assert_eq!(whole.id[w] as usize, w);
            assert_eq!(part.x[p], whole.x[w]);
            assert_eq!(part.mass[p], whole.mass[w]);
            assert_eq!(part.volume0[p], whole.volume0[w]);
            assert_eq!(part.pressure[p], whole.pressure[w]);
        }
    }
    assert!(whole.pressure.iter().any(|&p| p > 0.0));
}
