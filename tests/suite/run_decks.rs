//! Whole runs through the binary: every output file of docs/deck.md, 2D and 3D, repeatability,
//! the blow-up guard and the protection of an earlier run.

use crate::common;
use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::Path;

fn run_ok(deck: &Path, out: &Path, extra: &[&str]) {
    let mut args = vec![
        "run",
        deck.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let o = pmpm(&args);
    assert!(
        o.status.success(),
        "run failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn check_outputs(out: &Path, dim: usize, end_time: f64, probes: bool) {
    for f in ["run.toml", "series.csv", "particles.pvd"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    assert_eq!(out.join("probes.csv").is_file(), probes);
    let f0 = std::fs::read_to_string(out.join("frames/particles_000000.csv")).unwrap();
    let head = if dim == 2 {
        "id,x,y,vx,vy,pressure,mass,volume,material"
    } else {
        "id,x,y,z,vx,vy,vz,pressure,mass,volume,material"
    };
    assert_eq!(f0.lines().next().unwrap(), head);
    assert!(out.join("frames/particles_000000.vtu").is_file());
    let series = std::fs::read_to_string(out.join("series.csv")).unwrap();
    let mut lines = series.lines();
    assert_eq!(
        lines.next().unwrap(),
        "frame,time,step,dt,kinetic_energy,max_speed,pressure_iterations,wall_seconds,\
         fill_p1,fill_p99,fill_within_5pct,fill_nodes"
    );
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    let last = rows.last().unwrap();
    let t_last: f64 = last[1].parse().unwrap();
    assert!(
        (t_last - end_time).abs() < 1e-9,
        "ran to {t_last}, not {end_time}"
    );
    // every frame in series.csv has its files and is listed in the .pvd
    let pvd = std::fs::read_to_string(out.join("particles.pvd")).unwrap();
    for r in &rows {
        let n: usize = r[0].parse().unwrap();
        let name = format!("frames/particles_{n:06}");
        assert!(out.join(format!("{name}.csv")).is_file(), "{name}.csv");
        assert!(out.join(format!("{name}.vtu")).is_file(), "{name}.vtu");
        assert!(pvd.contains(&format!("{name}.vtu")));
    }
    if probes {
        let p = std::fs::read_to_string(out.join("probes.csv")).unwrap();
        let head = if dim == 2 {
            "time,base_pressure,base_vx,base_vy"
        } else {
            "time,base_pressure,base_vx,base_vy,base_vz"
        };
        assert_eq!(p.lines().next().unwrap(), head);
        let steps: usize = last[2].parse().unwrap();
        // a row at the start of every step and one for the final state
        assert_eq!(p.lines().count(), 1 + steps + 1);
    }
    // run.toml is a deck that validates again, with the defaults filled in
    let run = out.join("run.toml");
    let d = pmpm::Deck::load(&run).expect("run.toml is a valid deck");
    assert!(d.output.interval.is_some() && d.pmpm.is_some());
}

#[test]
fn a_2d_deck_writes_every_output_file() {
    let dir = scratch_dir("run-2d");
    let deck = dir.join("small.toml");
    std::fs::write(&deck, SMALL_2D).unwrap();
    run_ok(&deck, &dir.join("out"), &[]);
    check_outputs(&dir.join("out"), 2, 0.05, true);
}

#[test]
fn a_3d_deck_writes_every_output_file() {
    let dir = scratch_dir("run-3d");
    let deck = dir.join("small3d.toml");
    let text = r#"
[simulation]
dimension = 3
scheme = "explicit"
end_time = 0.03
cfl = 0.4
gravity = [0.0, 0.0, -9.81]
[grid]
size = [0.2, 0.1, 0.2]
cell_size = 0.02
[grid.boundary]
z_max = "open"
[[materials]]
name = "water"
density = 1000.0
bulk_modulus = 4.0e4
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0, 0.0], max = [0.06, 0.1, 0.1] }
[[bodies]]
material = "water"
shape = { type = "sphere", center = [0.15, 0.05, 0.12], radius = 0.03 }
velocity = [0.0, 0.0, -0.5]
[output]
interval = 0.01
[[output.probes]]
name = "base"
position = [0.01, 0.05, 0.0]
"#;
    std::fs::write(&deck, text).unwrap();
    run_ok(&deck, &dir.join("out"), &[]);
    check_outputs(&dir.join("out"), 3, 0.03, true);
}

#[test]
fn the_shipped_examples_are_valid() {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let mut n = 0;
    for e in std::fs::read_dir(examples).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let o = pmpm(&["check", p.to_str().unwrap()]);
            assert!(
                o.status.success(),
                "{}: {}",
                p.display(),
                String::from_utf8_lossy(&o.stderr)
            );
            let first = std::fs::read_to_string(&p).unwrap();
            assert!(
                first.starts_with('#'),
                "{}: starts with a comment on what it shows",
                p.display()
            );
            n += 1;
        }
    }
    assert!(n >= 3);
}

/// What `pmpm check` prints for the deck at `path` (relative to the repository), which it
/// accepts.
fn check(path: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    let o = pmpm(&["check", path.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `pmpm check` warns of a nearly incompressible solid under the explicit scheme without the
/// nodal averaging, and not once the averaging is on.
#[test]
fn check_warns_of_volumetric_locking() {
    let warning = "warning: materials \"rubber\": bulk_modulus / shear_modulus = 100 with the explicit scheme: such a nearly incompressible solid can lock";
    let without = check("validation/decks/elastic_column_explicit.toml");
    assert!(without.contains(warning), "{without}");
    let with = check("examples/elastic_column_2d.toml");
    assert!(!with.contains("can lock"), "{with}");
}

/// `pmpm check` suggests one pressure per cell for solids under the projection.
#[test]
fn check_suggests_cell_pressure_for_solids() {
    let warning =
        "warning: every material is a solid and the projection's pressure sits on the nodes";
    // the spinning-block example with the nodal pressure
    let dir = scratch_dir("check-cells");
    let deck = dir.join("spin_nodes.toml");
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/spinning_block_2d.toml"),
    )
    .unwrap()
    .replace("unknowns = \"cells\"", "unknowns = \"nodes\"");
    assert!(
        text.contains("unknowns = \"nodes\""),
        "the edit found its line"
    );
    std::fs::write(&deck, text).unwrap();
    // (an absolute path: joined to the repository's, it stays itself)
    let nodes = check(deck.to_str().unwrap());
    assert!(nodes.contains(warning), "{nodes}");
    for deck in [
        "examples/elastic_column_2d_projection.toml",
        "examples/spinning_block_2d.toml",
        "examples/dam_break_2d.toml",
    ] {
        let out = check(deck);
        assert!(!out.contains(warning), "{deck}: {out}");
    }
}

/// `pmpm check` names the explicit scheme's packing where the deck asks for it, and not
/// otherwise.
#[test]
fn check_names_the_explicit_packing() {
    let dir = scratch_dir("check-packing");
    let deck = dir.join("packed.toml");
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/dam_break_2d_explicit.toml"),
    )
    .unwrap()
        + "\n[pressure]\ndensity_correction = \"particles\"\n";
    std::fs::write(&deck, text).unwrap();
    let line = "  packing          particles spread to rest density";
    let packed = check(deck.to_str().unwrap());
    assert!(packed.contains(line), "{packed}");
    let plain = check("examples/dam_break_2d_explicit.toml");
    assert!(!plain.contains("packing"), "{plain}");
}

/// `pmpm check` lists the faces and says how the walls hold the material: by default they
/// only push, a mirror plane is its own kind.
#[test]
fn check_says_how_the_walls_hold() {
    let mud = check("examples/bingham_slump_2d.toml");
    assert!(
        mud.contains("  walls            x_min symmetry, x_max slip, y_min no_slip, y_max open; they only push (contact = \"separating\""),
        "{mud}"
    );
}

/// `pmpm check` names the viscous step limit only where it binds: a yield-stress fluid's
/// regularised viscosity, not water's under the projection.
#[test]
fn check_names_the_viscous_limit_only_where_it_binds() {
    let water = check("examples/dam_break_2d.toml");
    assert!(!water.contains("viscous limit"), "{water}");
    let mud = check("examples/bingham_slump_2d.toml");
    assert!(
        mud.contains("  viscous limit    h^2 rho / (2 D mu) = "),
        "{mud}"
    );
}

#[test]
fn runs_are_bitwise_repeatable_on_a_thread_count() {
    let projection = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace("transfer = \"apic\"", "transfer = \"flip\"");
    for (name, text) in [
        ("explicit", SMALL_2D.to_string()),
        ("projection", projection),
    ] {
        repeatable(name, &text);
    }
}

fn repeatable(name: &str, text: &str) {
    let dir = scratch_dir(&format!("repeat-{name}"));
    let deck = dir.join("small.toml");
    std::fs::write(&deck, text).unwrap();
    for threads in ["1", "2"] {
        let a = dir.join(format!("a{threads}"));
        let b = dir.join(format!("b{threads}"));
        run_ok(&deck, &a, &["--threads", threads]);
        run_ok(&deck, &b, &["--threads", threads]);
        for f in [
            "frames/particles_000005.vtu",
            "frames/particles_000005.csv",
            "probes.csv",
        ] {
            let fa = std::fs::read(a.join(f)).unwrap();
            let fb = std::fs::read(b.join(f)).unwrap();
            assert!(
                fa == fb,
                "{name}: {f} differs between two runs on {threads} threads"
            );
        }
    }
}

#[test]
fn an_earlier_run_is_not_overwritten_without_force() {
    let dir = scratch_dir("force");
    let deck = dir.join("small.toml");
    std::fs::write(&deck, SMALL_2D).unwrap();
    let out = dir.join("out");
    run_ok(&deck, &out, &[]);
    let before = std::fs::read(out.join("series.csv")).unwrap();
    let o = pmpm(&[
        "run",
        deck.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--force"));
    assert_eq!(std::fs::read(out.join("series.csv")).unwrap(), before);
    run_ok(&deck, &out, &["--force"]);
}

#[test]
fn an_output_directory_that_is_a_file_is_refused_and_kept() {
    let dir = scratch_dir("outfile");
    let deck = dir.join("small.toml");
    std::fs::write(&deck, SMALL_2D).unwrap();
    let file = dir.join("notes.txt");
    std::fs::write(&file, "mine").unwrap();
    let o = pmpm(&[
        "run",
        deck.to_str().unwrap(),
        "--output",
        file.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("the output directory is a file"),
        "{stderr}"
    );
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
}

#[test]
fn a_particle_leaving_through_an_open_face_stops_the_run_with_status_3() {
    let dir = scratch_dir("blowup");
    let deck = dir.join("leak.toml");
    // a block thrown at the open right face at 5 m/s reaches it within 0.05 s
    let text = SMALL_2D
        .replace("x_max = \"slip\"", "x_max = \"open\"")
        .replace(
            "particles_per_cell = 2",
            "particles_per_cell = 2\nvelocity = [5.0, 0.0]",
        )
        .replace("end_time = 0.05", "end_time = 0.2");
    std::fs::write(&deck, text).unwrap();
    let out = dir.join("out");
    let o = pmpm(&[
        "run",
        deck.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
        "-q",
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("left the grid") && stderr.contains("at step"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"));
    // frames written before the blow-up are kept, and series.csv lists them
    assert!(out.join("frames/particles_000000.csv").is_file());
    let series = std::fs::read_to_string(out.join("series.csv")).unwrap();
    assert!(series.lines().count() >= 2);
}

/// Kinetic energy and pressure iterations summed over a run's frames (series.csv).
fn energy_and_iterations(out: &Path) -> (f64, f64) {
    let series = std::fs::read_to_string(out.join("series.csv")).unwrap();
    let rows: Vec<Vec<f64>> = series
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    let last = rows.last().unwrap();
    (last[4], rows.iter().map(|r| r[6]).sum())
}

#[test]
fn the_ic0_preconditioner_gives_the_jacobi_answer_in_fewer_iterations() {
    let dir = scratch_dir("ic0");
    let base = SMALL_2D.replace("\"explicit\"", "\"projection\"");
    let mut figures = Vec::new();
    for pre in ["jacobi", "ic0"] {
        let deck = dir.join(format!("{pre}.toml"));
        let text = format!("{base}\n[pressure]\npreconditioner = \"{pre}\"\ntolerance = 1e-10\n");
        std::fs::write(&deck, text).unwrap();
        let out = dir.join(pre);
        run_ok(&deck, &out, &["--threads", "1"]);
        figures.push(energy_and_iterations(&out));
    }
    let ((e_j, it_j), (e_i, it_i)) = (figures[0], figures[1]);
    eprintln!("jacobi: energy {e_j:e}, iterations {it_j}; ic0: {e_i:e}, {it_i}");
    // the same converged pressure, so the same flow, to well within the solve tolerance's effect
    assert!((e_i - e_j).abs() <= 1e-6 * e_j, "{e_i} vs {e_j}");
    assert!(it_i < it_j, "ic0 {it_i} iterations, jacobi {it_j}");
}

#[test]
fn an_unconverged_pressure_solve_stops_the_run_with_status_3() {
    let dir = scratch_dir("unconverged");
    let deck = dir.join("tight.toml");
    let text = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace("transfer = \"apic\"", "transfer = \"pic\"")
        + "\n[pressure]\nmax_iterations = 2\n";
    std::fs::write(&deck, text).unwrap();
    let out = dir.join("out");
    let o = pmpm(&[
        "run",
        deck.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("the pressure solve did not converge"),
        "{stderr}"
    );
    assert!(stderr.contains("pressure.max_iterations"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    // the initial frame is kept
    assert!(out.join("frames/particles_000000.csv").is_file());
}

/// `pmpm bench` runs the steps asked for, times every phase of the projection step and
/// reports the figures a benchmark table needs, and leaves no frames behind.
#[test]
fn bench_reports_every_phase_and_the_figures() {
    let dir = scratch_dir("bench");
    let deck = dir.join("bench.toml");
    std::fs::write(&deck, SMALL_2D.replace("\"explicit\"", "\"projection\"")).unwrap();
    let o = pmpm(&[
        "--threads",
        "1",
        "bench",
        deck.to_str().unwrap(),
        "--steps",
        "5",
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for phase in [
        "| P2G |",
        "| free-surface detection |",
        "| assembly |",
        "| pressure solve |",
        "| corrector |",
        "| G2P and move |",
        "| constitutive update |",
        "particle updates per second",
        "pressure iterations:",
    ] {
        assert!(stdout.contains(phase), "{phase} missing:\n{stdout}");
    }
    let bench = stdout.lines().find(|l| l.starts_with("BENCH ")).unwrap();
    assert!(bench.contains(" steps=5 "), "{bench}");
    assert!(bench.contains(" threads=1 "), "{bench}");
    // the phases add up to the step loop's wall time
    let field = |k: &str| -> f64 {
        bench
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix(&format!("{k}=")))
            .unwrap()
            .parse()
            .unwrap()
    };
    // every phase the line names after the memory figures, whatever phases the step has;
    // each is rounded to 1e-4 s, so 14 of them and the total agree within 1e-3
    let phases: f64 = bench
        .split(" bytes_per_particle=")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .skip(1)
        .map(|kv| kv.split_once('=').unwrap().1.parse::<f64>().unwrap())
        .sum();
    for k in ["p2g", "viscosity", "pressure", "density", "g2p", "other"] {
        field(k);
    }
    assert!((phases - field("wall_s")).abs() < 1e-3, "{bench}");
    // ns per particle and step: the step loop's seconds over steps x particles (wall_s is
    // rounded to 1e-4 s)
    let per = 1e9 * field("wall_s") / (5.0 * field("particles"));
    let slack = 1e9 * 1e-4 / (5.0 * field("particles")) + 0.1;
    assert!(
        (field("ns_per_particle_step") - per).abs() <= slack,
        "{bench}"
    );
    assert!(stdout.contains("| ns/particle/step |"), "{stdout}");
    assert!(!dir.join("out").exists());
}

/// `pmpm check` prints what the run will be (particles per body, materials, steps, output size,
/// memory) and warns of what commonly goes wrong: too few particles per cell, overlapping
/// bodies, an open face that gravity pulls the material through.
#[test]
fn check_summarises_the_run_and_warns() {
    let dir = scratch_dir("check-warnings");
    let deck = dir.join("deck.toml");
    let text = SMALL_2D
        .replace("y_min = \"no_slip\"", "y_min = \"open\"")
        .replace("particles_per_cell = 2", "particles_per_cell = 1")
        + "\n[[bodies]]\nmaterial = \"water\"\nshape = { type = \"box\", min = [0.05, 0.0], max = [0.15, 0.1] }\nparticles_per_cell = 2\n";
    std::fs::write(&deck, text).unwrap();
    let o = pmpm(&["check", deck.to_str().unwrap()]);
    assert!(o.status.success());
    let out = String::from_utf8_lossy(&o.stdout);
    for line in [
        "  bodies[0]        25 particles of \"water\" (1 per cell per direction)",
        "  bodies[1]        100 particles of \"water\" (2 per cell per direction)",
        "  material         \"water\": newtonian, density 1000 kg/m3, viscosity 1e-3 Pa s, bulk modulus 4e4 Pa",
        "  wave limit       h / c = 3.162e-3 s (c the sound speed): about 40 steps or more to t = 0.05",
        "  particles        125",
        "warning: bodies[0].particles_per_cell = 1: fewer than 2 particles per cell per direction",
        "warning: bodies[0] and bodies[1] overlap: 50 particles of bodies[1] lie inside bodies[0]",
        "warning: grid.boundary.y_min is open and gravity pulls the material towards it",
    ] {
        assert!(out.contains(line), "missing {line:?} in\n{out}");
    }
    assert!(out.contains("  steps            about "), "{out}");
    assert!(out.contains("  memory           about "), "{out}");
    assert!(out.contains(": 6 frames of about "), "{out}");
}

/// `pmpm check` warns of water that starts inside a rigid body, and names the free-surface
/// method that runs: the level set, with rigid bodies or without.
#[test]
fn check_warns_of_water_inside_a_rigid_body() {
    let warning = "warning: bodies[0] reaches into rigid_bodies[0]";
    let dir = scratch_dir("check-inside");
    let deck = dir.join("inside.toml");
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/dam_break_obstacle_2d.toml"),
    )
    .unwrap()
    .replace("max = [0.1455, 0.292]", "max = [0.3, 0.292]");
    assert!(
        text.contains("max = [0.3, 0.292]"),
        "the edit found its line"
    );
    std::fs::write(&deck, text).unwrap();
    let inside = check(deck.to_str().unwrap());
    assert!(inside.contains(warning), "{inside}");
    let apart = check("examples/dam_break_obstacle_2d.toml");
    assert!(!apart.contains("reaches into"), "{apart}");
    assert!(apart.contains("free surface from the level set"), "{apart}");
    let plain = check("examples/dam_break_2d.toml");
    assert!(plain.contains("free surface from the level set"), "{plain}");
}

/// Under the projection a fluid deck without `transfer` runs APIC, and `pmpm check` warns of
/// FLIP, whose particle noise enters the particles' volumes.
#[test]
fn projection_defaults_to_apic_and_check_warns_of_flip() {
    let warning = "warning: simulation.transfer: \"flip\" with the projection scheme";
    let dir = scratch_dir("check-flip");
    let example = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/dam_break_2d.toml"),
    )
    .unwrap();
    assert!(
        example.contains("transfer = \"apic\"\n"),
        "the edit finds its line"
    );
    let deck = dir.join("default.toml");
    std::fs::write(&deck, example.replace("transfer = \"apic\"\n", "")).unwrap();
    let default = check(deck.to_str().unwrap());
    assert!(default.contains("  transfer         Apic,"), "{default}");
    assert!(!default.contains(warning), "{default}");
    let deck = dir.join("flip.toml");
    std::fs::write(
        &deck,
        example.replace("transfer = \"apic\"\n", "transfer = \"flip\"\n"),
    )
    .unwrap();
    let flip = check(deck.to_str().unwrap());
    assert!(flip.contains(warning), "{flip}");
}

/// `pmpm check` says how much PIC's share of a FLIP blend damps, (1 - r) h^2 / (6 dt) for
/// linear shapes: in the explicit yield-stress twin, at its viscous step of 3.324e-5 s and
/// h = 0.01 m, 5.0e-5 m2/s with r = 0.9999, and a hundred times that with the usual 0.99; APIC
/// adds none.
#[test]
fn check_reports_the_viscosity_of_the_pic_share() {
    let example = "examples/yield_block_slump_2d_explicit.toml";
    let said = |text: &str| -> String {
        text.lines()
            .find(|l| l.contains("damps like a kinematic viscosity"))
            .unwrap_or_default()
            .to_string()
    };
    let twin = check(example);
    assert!(said(&twin).contains("about 5.0e-5 m2/s"), "{twin}");
    assert!(said(&twin).contains("\"mud\" mu / rho = 2.0e-3"), "{twin}");
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(example)).unwrap();
    let line = text.lines().find(|l| l.starts_with("flip_ratio")).unwrap();
    let dir = scratch_dir("check-pic-share");
    let deck = dir.join("usual.toml");
    std::fs::write(&deck, text.replace(line, "flip_ratio = 0.99")).unwrap();
    let usual = check(deck.to_str().unwrap());
    assert!(said(&usual).contains("about 5.0e-3 m2/s"), "{usual}");
    assert_eq!(said(&check("examples/yield_block_slump_2d.toml")), "");
}

/// `pmpm validate --help` names every case `--case` accepts.
#[test]
fn validate_help_names_every_case() {
    let out = pmpm(&["validate", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout).replace(char::is_whitespace, "");
    for case in pmpm_cli::validation::case_names() {
        assert!(help.contains(case), "{case} missing from: {help}");
    }
}

#[test]
fn check_warns_of_a_rigid_body_thinner_than_two_cells() {
    let dir = scratch_dir("check-thin");
    let deck = dir.join("thin.toml");
    // the example's obstacle, 9 cells wide, cut down to a plate 1.5 cells thick
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/dam_break_obstacle_2d.toml"),
    )
    .unwrap()
    .replace(
        "min = [0.292, 0.0], max = [0.316,",
        "min = [0.292, 0.0], max = [0.296,",
    );
    assert!(text.contains("max = [0.296,"), "the edit found its line");
    std::fs::write(&deck, text).unwrap();
    let thin = check(deck.to_str().unwrap());
    assert!(
        thin.contains("warning: rigid_bodies[0] (\"obstacle\") is 1.50 cells thick along x"),
        "{thin}"
    );
    // the obstacle as shipped, and its height of 18.5 cells, give no warning
    let apart = check("examples/dam_break_obstacle_2d.toml");
    assert!(!apart.contains("cells thick"), "{apart}");
}

/// `pmpm init` writes a starter deck (2D, and 3D) that `check` accepts and that runs, with
/// its gauges; it does not replace a file without --force.
#[test]
fn init_writes_a_starter_deck_that_checks_and_runs() {
    let dir = scratch_dir("init");
    for dim in ["2", "3"] {
        let deck = dir.join(format!("starter_{dim}d.toml"));
        let d = deck.to_str().unwrap();
        let o = pmpm(&["init", d, "--dimension", dim]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let o = pmpm(&["check", d]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let out = dir.join(format!("out{dim}"));
        let o = pmpm(&[
            "bench",
            d,
            "--steps",
            "3",
            "--output",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let gauges = std::fs::read_to_string(out.join("gauges.csv")).unwrap();
        assert!(gauges.starts_with("time,middle_height"), "{gauges}");
        // the header, the state at t = 0 and the three steps
        assert_eq!(gauges.lines().count(), 5, "{gauges}");
        // a second init leaves the file alone
        std::fs::write(&deck, "mine").unwrap();
        let o = pmpm(&["init", d, "--dimension", dim]);
        assert_eq!(o.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&o.stderr).contains("--force"));
        assert_eq!(std::fs::read_to_string(&deck).unwrap(), "mine");
    }
}

/// A speed that runs away (here one particle's, set to 1e30 m/s) would shrink the adaptive
/// step to nothing and the run would crawl without end: the driver stops it as a blow-up.
#[test]
fn a_stable_step_that_collapses_stops_the_run_as_a_blow_up() {
    let d = common::deck(common::SMALL_2D);
    let mut sim = pmpm::scheme::Simulation::<2>::new(&d).unwrap();
    sim.particles.v[0] = pmpm::grid::Vector::<2>::new(1e30, 0.0);
    let mut driver = pmpm::driver::Driver::new(pmpm::build::clock(&d));
    match driver.step(&mut sim) {
        Err(pmpm::Error::BlowUp(m)) => assert!(m.contains("stable step fell"), "{m}"),
        other => panic!("expected a blow-up, got {other:?}"),
    }
    assert_eq!(sim.time, 0.0, "no step was taken");
}

/// `pmpm check` refuses a free body placed through another rigid body (the contact parts
/// bodies that meet, not one that starts inside another; it was a warning), naming both, and
/// not bodies that touch.
#[test]
fn check_refuses_a_free_body_that_starts_inside_another() {
    let error =
        "rigid_bodies[0].shape: the free body \"box\" overlaps rigid_bodies[1] (\"pier\") at t = 0";
    let dir = scratch_dir("check-free-overlap");
    let deck = dir.join("floating.toml");
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/floating_box_2d.toml"),
    )
    .unwrap();
    let block = "\n[[rigid_bodies]]\nname = \"pier\"\nshape = { type = \"box\", min = [LO, 0.0], max = [HI, 0.5] }\n";
    let (cx, half) = (1.5, 0.15); // the box spans x 1.35 to 1.65
    for (lo, hi, refused) in [(cx + half - 0.05, 1.8, true), (cx + half, 1.8, false)] {
        let with = format!(
            "{text}{}",
            block
                .replace("LO", &lo.to_string())
                .replace("HI", &hi.to_string())
        );
        std::fs::write(&deck, with).unwrap();
        let o = pmpm(&["check", deck.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(
            o.status.code(),
            Some(if refused { 2 } else { 0 }),
            "pier from x = {lo}: {err}"
        );
        assert_eq!(err.contains(error), refused, "pier from x = {lo}: {err}");
    }
}

/// A deck with neither `dt` nor `cfl` runs with the adaptive step at cfl = 0.4, as
/// docs/deck.md says (it used to be refused), and its run.toml says so.
#[test]
fn a_deck_without_dt_or_cfl_steps_at_the_default_cfl() {
    let dir = scratch_dir("default-cfl");
    let deck = dir.join("deck.toml");
    assert!(SMALL_2D.contains("cfl = 0.4\n"));
    std::fs::write(&deck, SMALL_2D.replace("cfl = 0.4\n", "")).unwrap();
    let out = dir.join("out");
    run_ok(&deck, &out, &[]);
    let run: toml::Table =
        toml::from_str(&std::fs::read_to_string(out.join("run.toml")).unwrap()).unwrap();
    assert_eq!(run["simulation"]["cfl"].as_float(), Some(0.4));
    assert!(run["simulation"].get("dt").is_none());
}
