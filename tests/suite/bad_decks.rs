//! Bad decks: each gives exit status 2, writes nothing, and prints one message that names the
//! file, the key (with line and column where TOML gives them) and what is wrong. The whole
//! message is checked, word for word.

use crate::common;
use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::Path;
use std::process::{Command, Output};

/// Runs pmpm with `dir` as the working directory, so that the deck is named `bad.toml` in the
/// message, as a user in that directory would name it.
fn pmpm_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pmpm"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("the pmpm binary runs")
}

/// The small deck with each `(from, to)` applied; each `from` must occur exactly once.
fn edit(changes: &[(&str, &str)]) -> String {
    let mut d = SMALL_2D.to_string();
    for (from, to) in changes {
        assert_eq!(d.matches(from).count(), 1, "`{from}` must occur once");
        d = d.replacen(from, to, 1);
    }
    d
}

/// (what, the bad deck, the message pmpm must print after `error: `)
fn cases() -> Vec<(&'static str, String, &'static str)> {
    let no_grid = {
        let d = SMALL_2D;
        let start = d.find("[grid]").unwrap();
        let end = d.find("[[materials]]").unwrap();
        format!("{}{}", &d[..start], &d[end..])
    };
    vec![
        // unknown keys: the nearest valid key, and the valid keys
        (
            "unknown key",
            edit(&[("end_time = 0.05", "endtime = 0.05")]),
            "bad.toml:5:1: simulation.endtime: unknown key; did you mean `end_time`? (valid keys: dimension, scheme, end_time, dt, cfl, max_dt, gravity, transfer, flip_ratio, shape_function, stress_update, volumetric_averaging, sort_interval, damping, land_on_frames, volume_limits, viscosity, viscosity_tolerance, viscosity_max_iterations)",
        ),
        (
            "unknown key, another name for a key",
            edit(&[("density = 1000.0", "rho = 1000.0")]),
            "bad.toml:23:1: materials[0].rho: unknown key; did you mean `density`? (valid keys: name, model, density, viscosity, bulk_modulus, yield_stress, papanastasiou_exponent, consistency, flow_index, shear_modulus, undrained_shear_strength)",
        ),
        (
            "unknown table",
            edit(&[("[output]", "[outputs]")]),
            "bad.toml:32:2: outputs: unknown key; did you mean `output`? (valid keys: pmpm, about, simulation, grid, pressure, materials, bodies, rigid_bodies, inflows, damping_zones, output)",
        ),
        // unknown values: the nearest allowed value, and the allowed values
        (
            "unknown scheme",
            edit(&[("scheme = \"explicit\"", "scheme = \"implicit\"")]),
            "bad.toml:4:10: simulation.scheme: unknown value \"implicit\"; did you mean \"explicit\"? (allowed: \"projection\", \"explicit\")",
        ),
        (
            "unknown transfer",
            edit(&[("transfer = \"apic\"", "transfer = \"flipp\"")]),
            "bad.toml:8:12: simulation.transfer: unknown value \"flipp\"; did you mean \"flip\"? (allowed: \"pic\", \"flip\", \"apic\")",
        ),
        (
            "unknown shape_function",
            edit(&[(
                "transfer = \"apic\"",
                "transfer = \"apic\"\nshape_function = \"quadratic\"",
            )]),
            "bad.toml:9:18: simulation.shape_function: unknown value \"quadratic\" (allowed: \"linear\", \"gimp\", \"bspline2\", \"bspline3\")",
        ),
        (
            "unknown stress_update",
            edit(&[(
                "transfer = \"apic\"",
                "transfer = \"apic\"\nstress_update = \"mls\"",
            )]),
            "bad.toml:9:17: simulation.stress_update: unknown value \"mls\"; did you mean \"musl\"? (allowed: \"musl\", \"usl\")",
        ),
        (
            "unknown volumetric_averaging",
            edit(&[(
                "transfer = \"apic\"",
                "transfer = \"apic\"\nvolumetric_averaging = \"fbar\"",
            )]),
            "bad.toml:9:24: simulation.volumetric_averaging: unknown value \"fbar\" (allowed: \"none\", \"nodal\")",
        ),
        (
            "volumetric_averaging with the projection",
            edit(&[
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("transfer = \"apic\"", "transfer = \"apic\"\nvolumetric_averaging = \"nodal\""),
            ]),
            "bad.toml: simulation.volumetric_averaging: is for scheme = \"explicit\" (against the locking of its equation of state); the projection's pressure already keeps one volume constraint per node: remove the key or set it to \"none\"",
        ),
        (
            "unknown boundary kind",
            edit(&[("y_min = \"no_slip\"", "y_min = \"noslip\"")]),
            "bad.toml:18:9: grid.boundary.y_min: unknown value \"noslip\"; did you mean \"no_slip\"? (allowed: \"slip\", \"no_slip\", \"open\", \"outflow\", \"periodic\", \"symmetry\")",
        ),
        (
            "unknown moving-wall type",
            edit(&[(
                "y_max = \"open\"",
                "y_max = { type = \"wall\", velocity = [1.0, 0.0] }",
            )]),
            "bad.toml:19:18: grid.boundary.y_max.type: unknown value \"wall\" (allowed: \"slip\", \"no_slip\", \"open\", \"outflow\", \"periodic\", \"symmetry\")",
        ),
        (
            "unknown output format",
            edit(&[("formats = [\"vtk\", \"csv\"]", "formats = [\"vtu\", \"csv\"]")]),
            "bad.toml:34:12: output.formats[0]: unknown value \"vtu\"; did you mean \"vtk\"? (allowed: \"vtk\", \"csv\", \"grid\")",
        ),
        (
            "unknown pressure.solver",
            edit(&[("[[materials]]", "[pressure]\nsolver = \"cg\"\n\n[[materials]]")]),
            "bad.toml:22:10: pressure.solver: unknown value \"cg\"; did you mean \"pcg\"? (allowed: \"pcg\", \"direct\")",
        ),
        (
            "unknown pressure.preconditioner",
            edit(&[(
                "[[materials]]",
                "[pressure]\npreconditioner = \"multgrid\"\n\n[[materials]]",
            )]),
            "bad.toml:22:18: pressure.preconditioner: unknown value \"multgrid\"; did you mean \"multigrid\"? (allowed: \"jacobi\", \"ic0\", \"multigrid\")",
        ),
        // wrong types
        (
            "a number where a name belongs",
            edit(&[("scheme = \"explicit\"", "scheme = 2")]),
            "bad.toml:4:10: simulation.scheme: must be one of \"projection\", \"explicit\" (in quotes)",
        ),
        (
            "text where a number belongs",
            edit(&[("cell_size = 0.02", "cell_size = \"fine\"")]),
            "bad.toml:13:13: grid.cell_size: must be a number, got \"fine\"",
        ),
        (
            "a fraction for the dimension",
            edit(&[("dimension = 2", "dimension = 2.5")]),
            "bad.toml:3:13: simulation.dimension: must be 2 or 3, got 2.5",
        ),
        (
            "single brackets for [[materials]]",
            edit(&[("[[materials]]", "[materials]")]),
            "bad.toml:21:1: materials: must be a list of tables: write [[materials]] (double brackets) above each entry, got [materials]",
        ),
        (
            "a boolean in a vector",
            edit(&[("gravity = [0.0, -9.81]", "gravity = [0.0, true]")]),
            "bad.toml:7:11: simulation.gravity[1]: must be a number or an expression in quotes (in x, y, z, t)",
        ),
        // missing keys
        (
            "missing dimension",
            edit(&[("dimension = 2\n", "")]),
            "bad.toml:2:1: simulation.dimension: is required but missing",
        ),
        (
            "missing end_time",
            edit(&[("end_time = 0.05\n", "")]),
            "bad.toml:2:1: simulation.end_time: is required but missing",
        ),
        (
            "missing grid.cell_size",
            edit(&[("cell_size = 0.02\n", "")]),
            "bad.toml:10:1: grid.cell_size: is required but missing",
        ),
        (
            "missing [grid]",
            no_grid,
            "bad.toml:1:1: grid: the [grid] table is required but missing",
        ),
        (
            "both dt and cfl",
            edit(&[("cfl = 0.4", "cfl = 0.4\ndt = 1.0e-4")]),
            "bad.toml: simulation.cfl: give either a fixed dt or an adaptive cfl, not both",
        ),
        (
            "explicit scheme without a bulk modulus",
            edit(&[("bulk_modulus = 4.0e4\n", "")]),
            "bad.toml: materials[0].bulk_modulus: is required by scheme = \"explicit\" (equation of state p = K (1 - J))",
        ),
        // zero and negative values
        (
            "zero end_time",
            edit(&[("end_time = 0.05", "end_time = 0.0")]),
            "bad.toml: simulation.end_time: must be > 0, got 0",
        ),
        (
            "negative dt",
            edit(&[("cfl = 0.4", "dt = -1.0e-4")]),
            "bad.toml: simulation.dt: must be > 0, got -0.0001",
        ),
        (
            "zero cfl",
            edit(&[("cfl = 0.4", "cfl = 0.0")]),
            "bad.toml: simulation.cfl: must be in (0, 1], got 0",
        ),
        (
            "zero cell_size",
            edit(&[("cell_size = 0.02", "cell_size = 0.0")]),
            "bad.toml: grid.cell_size: must be > 0, got 0",
        ),
        (
            "negative density",
            edit(&[("density = 1000.0", "density = -1000.0")]),
            "bad.toml: materials[0].density: must be > 0, got -1000",
        ),
        (
            "negative viscosity",
            edit(&[("viscosity = 1.0e-3", "viscosity = -1.0e-3")]),
            "bad.toml: materials[0].viscosity: must be >= 0, got -0.001",
        ),
        (
            "zero bulk_modulus",
            edit(&[("bulk_modulus = 4.0e4", "bulk_modulus = 0.0")]),
            "bad.toml: materials[0].bulk_modulus: must be > 0, got 0",
        ),
        // the models' own keys
        (
            "a key of another model",
            edit(&[("density = 1000.0", "density = 1000.0\nshear_modulus = 1.0e5")]),
            "bad.toml: materials[0].shear_modulus: is not a key of model = \"newtonian\" (its keys: viscosity (optional))",
        ),
        (
            "bingham without its yield stress",
            edit(&[("density = 1000.0", "model = \"bingham\"\ndensity = 1000.0\npapanastasiou_exponent = 100.0")]),
            "bad.toml: materials[0].yield_stress: is required by model = \"bingham\" (its keys: viscosity, yield_stress, papanastasiou_exponent)",
        ),
        (
            "bingham without its exponent",
            edit(&[("density = 1000.0", "model = \"bingham\"\ndensity = 1000.0\nyield_stress = 10.0")]),
            "bad.toml: materials[0].papanastasiou_exponent: is required by model = \"bingham\" (its keys: viscosity, yield_stress, papanastasiou_exponent); it sets how rigid the unyielded material is (a creep viscosity of about yield_stress * m) and so the time step: try m such that yield_stress * m is 100 to 1000 times the viscosity",
        ),
        (
            "bingham without a plastic viscosity",
            edit(&[
                ("density = 1000.0", "model = \"bingham\"\ndensity = 1000.0\nyield_stress = 10.0\npapanastasiou_exponent = 100.0"),
                ("viscosity = 1.0e-3\n", ""),
            ]),
            "bad.toml: materials[0].viscosity: must be > 0: it is the plastic viscosity of model = \"bingham\"",
        ),
        (
            "herschel_bulkley with a viscosity",
            edit(&[("density = 1000.0", "model = \"herschel_bulkley\"\ndensity = 1000.0")]),
            "bad.toml: materials[0].viscosity: is not a key of model = \"herschel_bulkley\" (its keys: consistency, flow_index, yield_stress, papanastasiou_exponent)",
        ),
        (
            "a negative flow index",
            edit(&[
                ("density = 1000.0", "model = \"herschel_bulkley\"\ndensity = 1000.0\nconsistency = 1.0\nflow_index = -0.5\nyield_stress = 1.0\npapanastasiou_exponent = 100.0"),
                ("viscosity = 1.0e-3\n", ""),
            ]),
            "bad.toml: materials[0].flow_index: must be > 0, got -0.5",
        ),
        (
            "von_mises without c_u",
            edit(&[
                ("density = 1000.0", "model = \"von_mises\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
            ]),
            "bad.toml: materials[0].undrained_shear_strength: is required by model = \"von_mises\" (its keys: shear_modulus, undrained_shear_strength)",
        ),
        (
            "a zero shear modulus",
            edit(&[("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 0.0")]),
            "bad.toml: materials[0].shear_modulus: must be > 0, got 0",
        ),
        (
            "fixed dt above a solid's pressure wave limit (explicit)",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e7"),
                ("viscosity = 1.0e-3\n", ""),
                ("bulk_modulus = 4.0e4", "bulk_modulus = 4.0e7"),
                ("cfl = 0.4", "dt = 1.0e-3"),
            ]),
            "bad.toml: simulation.dt: 0.001 s is above the explicit stability limit h / c = 8.660e-5 s (h = 0.02, fastest sound speed c = 230.9401 m/s); lower dt or use cfl",
        ),
        (
            "fixed dt above a solid's shear wave limit (projection)",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e7"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("cfl = 0.4", "dt = 1.0e-3"),
            ]),
            "bad.toml: simulation.dt: 0.001 s is above the explicit stability limit h / c = 2.000e-4 s (h = 0.02, fastest shear wave speed sqrt(G / rho) c = 100.0000 m/s); lower dt or use cfl",
        ),
        (
            "fixed dt above a Bingham fluid's explicit viscous limit",
            edit(&[
                ("density = 1000.0", "model = \"bingham\"\ndensity = 1000.0\nyield_stress = 100.0\npapanastasiou_exponent = 1000.0"),
                ("viscosity = 1.0e-3", "viscosity = 1.0"),
                ("scheme = \"explicit\"", "scheme = \"projection\"\nviscosity = \"explicit\""),
                ("cfl = 0.4", "dt = 1.0e-3"),
            ]),
            "bad.toml: simulation.dt: 0.001 s is above the viscous stability limit h^2 rho / (2 D mu) = 1.000e-6 s of material \"water\" (largest viscosity mu = 1.0000e5 Pa s); lower dt or use cfl",
        ),
        (
            "a volume correction of 1 or more",
            format!("{SMALL_2D}\n[pressure]\nvolume_correction = 1.5\n"),
            "bad.toml: pressure.volume_correction: must be >= 0 and < 1 (a fraction of the drift given back per step), got 1.5",
        ),
        (
            "a correction of J under the explicit scheme",
            format!("{SMALL_2D}\n[pressure]\ndensity_correction = \"positions\"\n"),
            "bad.toml: pressure.density_correction: \"positions\" applies to the projection: under the explicit scheme J is the equation of state's measure of the pressure, which a correction of J would overwrite; use \"particles\" (the particles packed to rest density, J left as it is) or \"none\"",
        ),
        (
            "cut-cell rigid faces with B-splines",
            format!(
                "{}\n[pressure]\nrigid_faces = \"cut\"\n",
                SMALL_2D.replace(
                    "scheme = \"explicit\"",
                    "scheme = \"projection\"\nshape_function = \"bspline2\""
                )
            ),
            "bad.toml: pressure.rigid_faces: \"cut\" needs shape_function = \"linear\" or \"gimp\", free_surface = \"level_set\" and unknowns = \"nodes\" (this deck has \"bspline2\", \"level_set\", \"nodes\"); use \"nodes\" or leave the key out",
        ),
        (
            "no pressure pass",
            format!("{SMALL_2D}\n[pressure]\npasses = 0\n"),
            "bad.toml: pressure.passes: must be >= 1 (1: one solve per step), got 0",
        ),
        // one pressure per cell
        (
            "cell pressure with a fluid",
            edit(&[
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\n\n[[bodies]]"),
                ("transfer = \"apic\"", "transfer = \"apic\"\nstress_update = \"usl\""),
            ]),
            "bad.toml: materials[0].model: \"water\" is a fluid, and pressure.unknowns = \"cells\" is for solids: one pressure per cell leaves velocity modes that only a shear stiffness holds (a water column at rest stirs up to 0.07 m/s in 2 s); use unknowns = \"nodes\"",
        ),
        (
            "cell pressure with the incremental form",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\nbeta = 0.5\n\n[[bodies]]"),
            ]),
            "bad.toml: pressure.beta: must be 0 with pressure.unknowns = \"cells\" (the cell pressure is solved whole, not as an increment), got 0.5",
        ),
        (
            "cell pressure with the volume correction",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\nvolume_correction = 0.1\n\n[[bodies]]"),
            ]),
            "bad.toml: pressure.volume_correction: must be 0 with pressure.unknowns = \"cells\": each cell's divergence is already held at zero",
        ),
        (
            "cell pressure with the musl remap",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\n\n[[bodies]]"),
            ]),
            "bad.toml: simulation.stress_update: must be \"usl\" with pressure.unknowns = \"cells\": the cells hold the volume of v^(n+1), and the musl remap smooths that velocity before the strain rate is taken, so the volume drifts again (an elastic column lost 1e-4 of its volume in 0.4 s with linear shapes and 2e-3 with bspline2, sinking all the while)",
        ),
        (
            "cell pressure with the multigrid",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\npreconditioner = \"multigrid\"\n\n[[bodies]]"),
                ("transfer = \"apic\"", "transfer = \"apic\"\nstress_update = \"usl\""),
            ]),
            "bad.toml: pressure.preconditioner: must be \"jacobi\" or \"ic0\" with pressure.unknowns = \"cells\" (the multigrid is built for the nodal Laplacian), or use solver = \"direct\"",
        ),
        (
            "cell pressure on a periodic axis",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("x_min = \"slip\"\nx_max = \"slip\"", "x_min = \"periodic\"\nx_max = \"periodic\""),
                ("transfer = \"apic\"", "transfer = \"apic\"\nstress_update = \"usl\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\n\n[[bodies]]"),
            ]),
            "bad.toml: grid.boundary.x_min: a periodic axis is not built for pressure.unknowns = \"cells\" yet: use \"nodes\"",
        ),
        (
            "separating walls under the cell pressure",
            edit(&[
                ("density = 1000.0", "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5"),
                ("viscosity = 1.0e-3\n", ""),
                ("scheme = \"explicit\"", "scheme = \"projection\""),
                ("x_min = \"slip\"\n", "x_min = \"slip\"\ncontact = \"separating\"\n"),
                ("transfer = \"apic\"", "transfer = \"apic\"\nstress_update = \"usl\""),
                ("[[bodies]]", "[pressure]\nunknowns = \"cells\"\n\n[[bodies]]"),
            ]),
            "bad.toml: grid.boundary.contact: \"separating\" is not built for pressure.unknowns = \"cells\" yet: use \"bonded\", or unknowns = \"nodes\"",
        ),
        (
            "an unknown kind of wall contact",
            edit(&[("x_min = \"slip\"\n", "x_min = \"slip\"\ncontact = \"sticky\"\n")]),
            "bad.toml:17:11: grid.boundary.contact: unknown value \"sticky\" (allowed: \"separating\", \"bonded\")",
        ),
        (
            "an unknown wall friction",
            edit(&[("x_min = \"slip\"\n", "x_min = \"slip\"\nfriction = \"rough\"\n")]),
            "bad.toml:17:12: grid.boundary.friction: unknown value \"rough\" (allowed: \"none\", \"wall_law\")",
        ),
        (
            "the law of the wall with a mud",
            edit(&[
                ("x_min = \"slip\"\n", "x_min = \"slip\"\nfriction = \"wall_law\"\n"),
                ("density = 1000.0", "model = \"bingham\"\ndensity = 1000.0\nyield_stress = 10.0\npapanastasiou_exponent = 100.0"),
            ]),
            "bad.toml: grid.boundary.friction: \"wall_law\" is the law of the wall of a Newtonian fluid with a viscosity; material \"water\" is not one (model Bingham, viscosity 0.001 Pa s)",
        ),
        (
            "an unknown place for the pressure",
            format!("{SMALL_2D}\n[pressure]\nunknowns = \"faces\"\n"),
            "bad.toml:41:12: pressure.unknowns: unknown value \"faces\"; did you mean \"nodes\"? (allowed: \"nodes\", \"cells\")",
        ),
        // shapes
        (
            "a key another kind of shape takes",
            edit(&[(
                "shape = { type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }",
                "shape = { type = \"sphere\", center = [0.05, 0.05], radius = 0.02, min = [0.0, 0.0] }",
            )]),
            "bad.toml: bodies[0].shape.min: is not a key of type = \"sphere\", which takes center, radius (and scale, rotate, translate)",
        ),
        (
            "a union of one shape",
            edit(&[(
                "shape = { type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }",
                "shape = { type = \"union\", shapes = [{ type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }] }",
            )]),
            "bad.toml: bodies[0].shape.shapes: needs at least two shapes, got 1",
        ),
        (
            "a bad radius inside a difference",
            edit(&[(
                "shape = { type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }",
                "shape = { type = \"difference\", shapes = [{ type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }, { type = \"sphere\", center = [0.0, 0.0], radius = -1.0 }] }",
            )]),
            "bad.toml: bodies[0].shape.shapes[1].radius: must be > 0, got -1",
        ),
        (
            "a mesh in 2D",
            edit(&[(
                "shape = { type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }",
                "shape = { type = \"mesh\", file = \"column.stl\" }",
            )]),
            "bad.toml: bodies[0].shape: a mesh is three-dimensional: with dimension = 2 use type = \"polygon\"",
        ),
        (
            "a 3D rotation in 2D",
            edit(&[(
                "shape = { type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1] }",
                "shape = { type = \"box\", min = [0.0, 0.0], max = [0.1, 0.1], rotate = [0.0, 0.0, 30.0] }",
            )]),
            "bad.toml: bodies[0].shape.rotate: in 2D is one angle in degrees (counter-clockwise)",
        ),
        (
            "a moving symmetry plane",
            edit(&[("x_max = \"slip\"", "x_max = { type = \"symmetry\", velocity = [0.0, 1.0] }")]),
            "bad.toml: grid.boundary.x_max.velocity: a symmetry plane stands still: a moving wall is \"slip\" or \"no_slip\"",
        ),
        // open boundaries
        (
            "an outflow face with a velocity",
            edit(&[("x_max = \"slip\"", "x_max = { type = \"outflow\", velocity = [1.0, 0.0] }")]),
            "bad.toml: grid.boundary.x_max.velocity: an open or outflow face imposes nothing: a velocity needs \"slip\" or \"no_slip\" (an inflow is an [[inflows]] entry)",
        ),
        (
            "an inflow on an open face",
            format!("{SMALL_2D}\n[[inflows]]\nmaterial = \"water\"\nface = \"y_max\"\nmin = [0.1, 0.2]\nmax = [0.2, 0.2]\nvelocity = [0.0, -0.1]\n"),
            "bad.toml: inflows[0].face: grid.boundary.y_max is \"open\": an inflow is a patch of a slip or no-slip face",
        ),
        (
            "an inflow off its face",
            format!("{SMALL_2D}\n[[inflows]]\nmaterial = \"water\"\nface = \"x_min\"\nmin = [0.01, 0.0]\nmax = [0.0, 0.05]\nvelocity = [0.1, 0.0]\n"),
            "bad.toml: inflows[0].min: must lie on the face x_min: its x component must be 0, got 0.01",
        ),
        (
            "an inflow that points out",
            format!("{SMALL_2D}\n[[inflows]]\nmaterial = \"water\"\nface = \"x_min\"\nmin = [0.0, 0.0]\nmax = [0.0, 0.05]\nvelocity = [-0.1, 0.0]\n"),
            "bad.toml: inflows[0].velocity: points out of the domain at (0, 0) at t = 0 (its x component is -0.1 on the face x_min): an inflow's velocity points into the grid",
        ),
        (
            "an inflow of a material the deck lacks",
            format!("{SMALL_2D}\n[[inflows]]\nmaterial = \"mud\"\nface = \"x_min\"\nmin = [0.0, 0.0]\nmax = [0.0, 0.05]\nvelocity = [0.1, 0.0]\n"),
            "bad.toml: inflows[0].material: no material named \"mud\" (defined: \"water\")",
        ),
        // damping zones
        (
            "a damping zone along z in 2D",
            format!("{SMALL_2D}\n[[damping_zones]]\naxis = \"z\"\nfrom = 0.3\nto = 0.4\nrate = 5.0\n"),
            "bad.toml: damping_zones[0].axis: must be one of \"x\", \"y\" (dimension = 2), got \"z\"",
        ),
        (
            "a damping zone past the grid",
            format!("{SMALL_2D}\n[[damping_zones]]\naxis = \"x\"\nfrom = 0.3\nto = 0.5\nrate = 5.0\n"),
            "bad.toml: damping_zones[0].to: must lie in the grid along x ([0, 0.4]), got 0.5",
        ),
        (
            "a damping zone thinner than a cell",
            format!("{SMALL_2D}\n[[damping_zones]]\naxis = \"x\"\nfrom = 0.39\nto = 0.4\nrate = 5.0\n"),
            "bad.toml: damping_zones[0].to: must be at least a cell (grid.cell_size = 0.02) from `from` = 0.39, got 0.4: the rate grows from 0 at `from` to `rate` at `to`, and a sudden rise reflects the waves the zone should absorb",
        ),
        (
            "a damping zone without a rate",
            format!("{SMALL_2D}\n[[damping_zones]]\naxis = \"x\"\nfrom = 0.3\nto = 0.4\nrate = 0.0\n"),
            "bad.toml: damping_zones[0].rate: must be > 0, got 0",
        ),
        // rigid bodies
        // rigid bodies of the general path and free bodies: the keys that do not go together
        (
            "a free body without a density",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\nmotion = \"free\"\n"),
            "bad.toml: rigid_bodies[0].density: a free body needs its density (kg/m^3)",
        ),
        (
            "a density on a prescribed body",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\ndensity = 500.0\n"),
            "bad.toml: rigid_bodies[0].density: is for motion = \"free\" (a prescribed body's motion does not depend on its mass)",
        ),
        (
            "a free body held along an axis it has not",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\nmotion = \"free\"\ndensity = 500.0\nfixed = [\"z\"]\n"),
            "bad.toml: rigid_bodies[0].fixed[0]: must be one of x, y, rotation, got \"z\"",
        ),
        (
            "a 2D angular velocity given as a vector",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\nangular_velocity = [0.0, 0.0, 1.0]\n"),
            "bad.toml: rigid_bodies[0].angular_velocity: in 2D is one number or expression of t (rad/s, counter-clockwise)",
        ),
        (
            "a free body's velocity as an expression",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\nmotion = \"free\"\ndensity = 500.0\nvelocity = [0.0, \"t\"]\n"),
            "bad.toml: rigid_bodies[0].velocity: of a free body is its value at t = 0: numbers, not expressions",
        ),
        (
            "smooth sides on a turning body",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\nangular_velocity = 1.0\nsides = \"smooth\"\n"),
            "bad.toml: rigid_bodies[0].sides: \"smooth\" is for a box that does not turn (an axis-aligned box moved by velocity alone); this body is held rough",
        ),
        (
            "a turning centre for a box that does not turn",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\ncentre = [0.2, 0.12]\n"),
            "bad.toml: rigid_bodies[0].centre: is the point a turning body turns about: give angular_velocity, or remove centre",
        ),
        (
            "a spin for a free body held from turning",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }}\nmotion = \"free\"\ndensity = 500.0\nfixed = [\"rotation\"]\nangular_velocity = 1.0\n"),
            "bad.toml: rigid_bodies[0].angular_velocity: is given for a body held from turning (fixed holds \"rotation\"): remove one of them",
        ),
        (
            "a free body across a wall",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"b\"\nshape = {{ type = \"sphere\", center = [0.2, 0.19], radius = 0.02 }}\nmotion = \"free\"\ndensity = 500.0\n"),
            "bad.toml: rigid_bodies[0].shape: of a free body must lie inside the grid: it reaches y = [0.1701, 0.2099] against the grid's [0, 0.2]",
        ),
        (
            "a moving half-space",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"floor\"\nshape = {{ type = \"half_space\", point = [0.0, 0.02], normal = [0.0, 1.0] }}\nvelocity = [0.1, 0.0]\n"),
            "bad.toml: rigid_bodies[0].shape: is unbounded (a half-space): only a body at rest may be, cut off at the grid",
        ),
        (
            "a rigid body's velocity of the wrong size",
            format!("{SMALL_2D}\n[[rigid_bodies]]\nname = \"gate\"\nshape = {{ type = \"box\", min = [0.1, 0.0], max = [0.12, 0.2] }}\nvelocity = [0.0, 1.0, 0.0]\n"),
            "bad.toml: rigid_bodies[0].velocity: must have 2 components (dimension = 2), got 3",
        ),
        (
            "zero output.interval",
            edit(&[("interval = 0.01", "interval = 0.0")]),
            "bad.toml: output.interval: must be > 0, got 0",
        ),
        (
            "negative output.checkpoint_interval",
            edit(&[(
                "interval = 0.01",
                "interval = 0.01\ncheckpoint_interval = -1.0",
            )]),
            "bad.toml: output.checkpoint_interval: must be > 0, got -1",
        ),
        (
            "a frame interval that asks for more than a million frames",
            edit(&[("interval = 0.01", "interval = 1e-300")]),
            "bad.toml: output.interval: gives 5.000e298 frames over end_time = 5.000000e-2 s, more than 1e6: raise it to at least 5.000e-8 s",
        ),
        (
            "a checkpoint interval that asks for more than a million checkpoints",
            edit(&[(
                "interval = 0.01",
                "interval = 0.01\ncheckpoint_interval = 1e-12",
            )]),
            "bad.toml: output.checkpoint_interval: gives 5.000e10 checkpoints over end_time = 5.000000e-2 s, more than 1e6: raise it to at least 5.000e-8 s",
        ),
        // the grid
        (
            "dimension 4",
            edit(&[("dimension = 2", "dimension = 4")]),
            "bad.toml: simulation.dimension: must be 2 or 3, got 4",
        ),
        (
            "wrong vector length",
            edit(&[("gravity = [0.0, -9.81]", "gravity = [0.0, 0.0, -9.81]")]),
            "bad.toml: simulation.gravity: must have 2 components (dimension = 2), got 3",
        ),
        (
            // a cell size in the wrong unit used to hang in setting up the particles
            "grid too fine to number its nodes",
            edit(&[("cell_size = 0.02", "cell_size = 1.0e-7")]),
            "bad.toml: grid.cell_size: gives a grid of 4000000 x 2000000 cells, too many: pmpm numbers at most 4294967295 grid nodes; use a larger cell_size",
        ),
        (
            "too many particles to number",
            edit(&[
                ("cell_size = 0.02", "cell_size = 2.5e-5"),
                ("max = [0.1, 0.1]", "max = [0.4, 0.2]"),
                ("particles_per_cell = 2", "particles_per_cell = 8"),
            ]),
            "bad.toml: bodies[0]: the bodies would hold up to 8.192e9 particles, too many: pmpm numbers at most 4294967295 particles; use a larger cell_size or fewer particles_per_cell",
        ),
        (
            "periodic on one face only",
            edit(&[("x_min = \"slip\"", "x_min = \"periodic\"")]),
            "bad.toml: grid.boundary.x_max: must be \"periodic\" too: x_min is periodic, and a periodic axis needs both faces",
        ),
        (
            "z face in 2D",
            edit(&[("y_max = \"open\"", "y_max = \"open\"\nz_min = \"slip\"")]),
            "bad.toml: grid.boundary.z_min: there is no such face in 2D",
        ),
        (
            "fixed dt above the explicit limit",
            edit(&[("cfl = 0.4", "dt = 0.01")]),
            "bad.toml: simulation.dt: 0.01 s is above the explicit stability limit h / c = 3.162e-3 s (h = 0.02, fastest sound speed c = 6.3246 m/s); lower dt or use cfl",
        ),
        // bodies, materials, probes
        (
            "body outside the grid",
            edit(&[("max = [0.1, 0.1]", "max = [0.5, 0.1]")]),
            "bad.toml: bodies[0].shape: extends outside the grid along x: the body spans [0, 0.5], the grid [0, 0.4]",
        ),
        (
            "body with no particle",
            edit(&[("max = [0.1, 0.1]", "max = [0.001, 0.001]")]),
            "bad.toml: bodies[0].shape: holds no particle: it is smaller than the particle spacing h / particles_per_cell = 0.01",
        ),
        (
            "unknown material name",
            edit(&[("material = \"water\"", "material = \"watr\"")]),
            "bad.toml: bodies[0].material: no material named \"watr\"; did you mean \"water\"? (defined: \"water\")",
        ),
        (
            "duplicate material name",
            edit(&[(
                "[[bodies]]",
                "[[materials]]\nname = \"water\"\ndensity = 900.0\nbulk_modulus = 4.0e4\n\n[[bodies]]",
            )]),
            "bad.toml: materials[1].name: \"water\" is defined twice",
        ),
        (
            "duplicate probe name",
            edit(&[(
                "position = [0.01, 0.01]",
                "position = [0.01, 0.01]\n\n[[output.probes]]\nname = \"base\"\nposition = [0.02, 0.02]",
            )]),
            "bad.toml: output.probes[1].name: \"base\" is used twice",
        ),
        (
            "probe outside the grid",
            edit(&[("position = [0.01, 0.01]", "position = [0.01, 0.3]")]),
            "bad.toml: output.probes[0].position: lies outside the grid along y: y = 0.3, the grid spans [0, 0.2]",
        ),
        // expressions
        (
            "bad expression",
            edit(&[("gravity = [0.0, -9.81]", "gravity = [\"0\", \"-9.81*sin(q*t)\"]")]),
            "bad.toml: simulation.gravity: bad expression: simulation.gravity[1] = \"-9.81*sin(q*t)\": unknown name `q`: the variables are x, y, z, t, the constant pi, and the functions sin, cos, tan, asin, acos, atan, atan2, sinh, cosh, tanh, exp, ln, log, log10, sqrt, abs, min, max, floor, ceil, round, signum",
        ),
        (
            // used to pass the check and blow the run up (exit status 3) at its first step
            "expression that is not a number",
            edit(&[("gravity = [0.0, -9.81]", "gravity = [\"0\", \"sqrt(-1)\"]")]),
            "bad.toml: simulation.gravity: bad expression: simulation.gravity[1] = \"sqrt(-1)\": gives NaN, not a finite number",
        ),
        (
            // exmex reads {u} as a variable: this used to panic
            "expression with braces",
            edit(&[(
                "particles_per_cell = 2",
                "particles_per_cell = 2\nvelocity = [\"{u}\", \"0\"]",
            )]),
            "bad.toml: bodies[0].velocity: bad expression: bodies[0].velocity[0] = \"{u}\": braces { } are not allowed; use ( ) and the variables x, y, z, t",
        ),
        (
            "expression missing an operand",
            edit(&[(
                "particles_per_cell = 2",
                "particles_per_cell = 2\nvelocity = [\"1 2\", \"0\"]",
            )]),
            "bad.toml: bodies[0].velocity: bad expression: bodies[0].velocity[0] = \"1 2\": an operator or a function lacks a value, or two values have no operator between them",
        ),
        (
            "implicit viscosity with the explicit scheme",
            edit(&[("scheme = \"explicit\"", "scheme = \"explicit\"\nviscosity = \"implicit\"")]),
            "bad.toml: simulation.viscosity: \"implicit\" is for scheme = \"projection\": the explicit scheme's step is held far below the viscous limit by the speed of sound; remove the key or set it to \"explicit\"",
        ),
        (
            "viscous solve tolerance out of range",
            edit(&[("cfl = 0.4", "cfl = 0.4\nviscosity_tolerance = 1.5")]),
            "bad.toml: simulation.viscosity_tolerance: must be in (0, 1) (a relative residual), got 1.5",
        ),
        // TOML syntax
        (
            "TOML syntax error",
            edit(&[("cfl = 0.4", "cfl = = 0.4")]),
            "bad.toml:6:7: (syntax): extra `=`, expected nothing",
        ),
        (
            "key given twice",
            edit(&[("cfl = 0.4", "cfl = 0.4\ncfl = 0.3")]),
            "bad.toml:7:1: (syntax): duplicate key: `cfl` is given twice",
        ),
    ]
}

#[test]
fn bad_decks_exit_2_write_nothing_and_say_exactly_what_is_wrong() {
    let cases = cases();
    assert!(cases.len() >= 20, "{} cases", cases.len());
    let mut names: Vec<_> = cases.iter().map(|c| c.0).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), cases.len(), "case names must be distinct");
    for (what, text, message) in cases {
        assert_ne!(text, SMALL_2D, "{what}: the case must change the deck");
        let dir = scratch_dir("bad-deck");
        std::fs::write(dir.join("bad.toml"), &text).unwrap();
        let expected = format!("error: {message}");
        // `run` without --output would write into out/bad under the working directory
        for args in [
            &["check", "bad.toml"][..],
            &["run", "bad.toml"][..],
            &["run", "bad.toml", "--output", "out"][..],
        ] {
            let out = pmpm_in(&dir, args);
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_eq!(
                out.status.code(),
                Some(2),
                "{what} ({}): {stderr}",
                args.join(" ")
            );
            assert_eq!(
                stderr.lines().next().unwrap_or(""),
                expected,
                "{what} ({})",
                args.join(" ")
            );
            assert_eq!(
                stderr.lines().count(),
                1,
                "{what} ({}): one message: {stderr}",
                args.join(" ")
            );
            assert!(
                out.stdout.is_empty(),
                "{what} ({}): {}",
                args.join(" "),
                String::from_utf8_lossy(&out.stdout)
            );
        }
        let written: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(written, ["bad.toml"], "{what}: nothing may be written");
    }
}

#[test]
fn the_deck_is_named_as_the_user_named_it() {
    let dir = scratch_dir("bad-decks-path");
    let deck = dir.join("typo.toml");
    std::fs::write(&deck, SMALL_2D.replace("end_time = 0.05", "endtime = 0.05")).unwrap();
    let out = pmpm(&["check", deck.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    // the typo sits on line 5 of the deck (the raw string starts with a newline)
    assert_eq!(
        stderr.lines().next().unwrap_or(""),
        format!(
            "error: {}:5:1: simulation.endtime: unknown key; did you mean `end_time`? (valid keys: dimension, scheme, end_time, dt, cfl, max_dt, gravity, transfer, flip_ratio, shape_function, stress_update, volumetric_averaging, sort_interval, damping, land_on_frames, volume_limits, viscosity, viscosity_tolerance, viscosity_max_iterations)",
            deck.display()
        )
    );
}

#[test]
fn a_missing_deck_file_is_a_clear_error() {
    let out = pmpm(&["check", "no/such/deck.toml"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("no/such/deck.toml") && stderr.contains("cannot read the deck"));
}
