//! Bad decks: each gives exit status 2, writes nothing, and says which key is wrong and why.

mod common;
use common::{pmpm, scratch_dir, SMALL_2D};

/// (what, change to the small deck, key the message must name, words it must contain)
fn cases() -> Vec<(&'static str, String, &'static str, &'static str)> {
    let d = SMALL_2D;
    vec![
        (
            "bad expression",
            d.replace("gravity = [0.0, -9.81]", "gravity = [\"0\", \"-9.81*sin(q*t)\"]"),
            "simulation.gravity",
            "bad expression: simulation.gravity[1] = \"-9.81*sin(q*t)\": unknown name `q`",
        ),
        (
            "periodic on one face only",
            d.replace("x_min = \"slip\"", "x_min = \"periodic\""),
            "grid.boundary.x_max",
            "must be \"periodic\" too: x_min is periodic",
        ),
        (
            "unknown key",
            d.replace("end_time = 0.05", "endtime = 0.05"),
            "simulation.endtime",
            "did you mean `end_time`?",
        ),
        (
            "wrong type",
            d.replace("cell_size = 0.02", "cell_size = \"fine\""),
            "grid.cell_size",
            "invalid type: string \"fine\"",
        ),
        (
            "negative density",
            d.replace("density = 1000.0", "density = -1000.0"),
            "materials[0].density",
            "must be > 0, got -1000",
        ),
        (
            "zero cell size",
            d.replace("cell_size = 0.02", "cell_size = 0.0"),
            "grid.cell_size",
            "must be > 0, got 0",
        ),
        (
            "body outside the grid",
            d.replace("max = [0.1, 0.1]", "max = [0.5, 0.1]"),
            "bodies[0].shape",
            "extends outside the grid along axis 0",
        ),
        (
            "unknown material name",
            d.replace("material = \"water\"", "material = \"watr\""),
            "bodies[0].material",
            "no material named \"watr\"; did you mean \"water\"?",
        ),
        (
            "wrong vector length",
            d.replace("gravity = [0.0, -9.81]", "gravity = [0.0, 0.0, -9.81]"),
            "simulation.gravity",
            "must have 2 components (dimension = 2), got 3",
        ),
        (
            "size not a whole number of cells",
            d.replace("size = [0.4, 0.2]", "size = [0.41, 0.2]"),
            "grid.size",
            "must be a whole number of cells",
        ),
        (
            "unknown enum value",
            d.replace("transfer = \"apic\"", "transfer = \"flipp\""),
            "simulation.transfer",
            "unknown value \"flipp\"; did you mean \"flip\"? (allowed: \"pic\", \"flip\", \"apic\")",
        ),
        (
            "missing [grid]",
            {
                let start = d.find("[grid]").unwrap();
                let end = d.find("[[materials]]").unwrap();
                format!("{}{}", &d[..start], &d[end..])
            },
            "grid",
            "is required but missing",
        ),
        (
            "unknown boundary kind",
            d.replace("y_min = \"no_slip\"", "y_min = \"noslip\""),
            "grid.boundary.y_min",
            "did you mean \"no_slip\"?",
        ),
        (
            "fixed dt above the explicit limit",
            d.replace("cfl = 0.4", "dt = 0.01"),
            "simulation.dt",
            "above the explicit stability limit",
        ),
        (
            "explicit scheme without a bulk modulus",
            d.replace("bulk_modulus = 4.0e4", ""),
            "materials[0].bulk_modulus",
            "is required by scheme = \"explicit\"",
        ),
        (
            "dimension 4",
            d.replace("dimension = 2", "dimension = 4"),
            "simulation.dimension",
            "must be 2 or 3, got 4",
        ),
        (
            "TOML syntax error",
            d.replace("cfl = 0.4", "cfl = = 0.4"),
            "(syntax)",
            "",
        ),
        (
            "z face in 2D",
            d.replace("y_max = \"open\"", "y_max = \"open\"\nz_min = \"slip\""),
            "grid.boundary.z_min",
            "there is no such face in 2D",
        ),
    ]
}

#[test]
fn bad_decks_exit_2_and_name_the_key() {
    let dir = scratch_dir("bad-decks");
    for (what, text, key, words) in cases() {
        assert_ne!(text, SMALL_2D, "{what}: the case must change the deck");
        let deck = dir.join("bad.toml");
        std::fs::write(&deck, &text).unwrap();
        let out_dir = dir.join("out");
        for cmd in ["run", "check"] {
            let mut args = vec![cmd, deck.to_str().unwrap()];
            if cmd == "run" {
                args.extend(["--output", out_dir.to_str().unwrap()]);
            }
            let out = pmpm(&args);
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{what} ({cmd}): {stderr}");
            assert!(
                stderr.contains(&format!(": {key}: ")) || stderr.contains(&format!(": {key} ")),
                "{what} ({cmd}): message does not name `{key}`: {stderr}"
            );
            assert!(
                stderr.contains(words),
                "{what} ({cmd}): `{words}` not in: {stderr}"
            );
            assert!(
                stderr.contains("bad.toml"),
                "{what}: file not named: {stderr}"
            );
            assert!(!stderr.contains("panicked"), "{what}: {stderr}");
            assert_eq!(stderr.lines().count(), 1, "{what}: one message: {stderr}");
            assert!(!out_dir.exists(), "{what}: nothing may be written");
        }
    }
}

#[test]
fn toml_errors_carry_line_and_column() {
    let dir = scratch_dir("bad-decks-line");
    let deck = dir.join("typo.toml");
    std::fs::write(&deck, SMALL_2D.replace("end_time = 0.05", "endtime = 0.05")).unwrap();
    let out = pmpm(&["check", deck.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    // the typo sits on line 5 of the deck (the raw string starts with a newline)
    assert!(
        stderr.contains("typo.toml:5:1: simulation.endtime"),
        "{stderr}"
    );
}

#[test]
fn a_missing_deck_file_is_a_clear_error() {
    let out = pmpm(&["check", "no/such/deck.toml"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("no/such/deck.toml") && stderr.contains("cannot read the deck"));
}
