//! Bodies from meshes: the shipped STL column fills the lattice as the primitive cylinder it
//! was exported from; a mesh with a hole is refused before anything runs.

use crate::common;

use common::{pmpm, scratch_dir};

/// examples/cylinder_collapse_3d.toml's water column (a 48-sided prism read from STL) and the
/// same column as `type = "cylinder"` hold the same lattice points, except within the
/// 48-gon's sagitta r (1 - cos(pi / 48)) = 0.11 mm of the curved face.
#[test]
fn an_stl_column_fills_as_its_cylinder() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples")
        .join("cylinder_collapse_3d.toml");
    let deck = pmpm::Deck::load(&path).unwrap();
    let mut prim = deck.clone();
    prim.bodies[0].shape = pmpm::deck::ShapeDeck {
        from: Some(vec![0.1, 0.1, 0.0]),
        to: Some(vec![0.1, 0.1, 0.1]),
        radius: Some(0.05),
        ..pmpm::deck::ShapeDeck::empty(pmpm::deck::ShapeKind::Cylinder)
    };
    let geo = pmpm::build::grid_geometry::<3>(&deck);
    let mesh = pmpm::build::particles::<3>(&deck, &geo).unwrap();
    let cyl = pmpm::build::particles::<3>(&prim, &geo).unwrap();
    let key = |x: &pmpm::grid::Vector<3>| {
        x.iter()
            .map(|c| (c * 1e6).round() as i64)
            .collect::<Vec<_>>()
    };
    let a: std::collections::HashSet<_> = mesh.x.iter().map(key).collect();
    let b: std::collections::HashSet<_> = cyl.x.iter().map(key).collect();
    let sagitta = 0.05 * (1.0 - (std::f64::consts::PI / 48.0).cos());
    for x in mesh.x.iter().chain(&cyl.x) {
        if a.contains(&key(x)) != b.contains(&key(x)) {
            let r = ((x[0] - 0.1).powi(2) + (x[1] - 0.1).powi(2)).sqrt();
            assert!(
                r > 0.05 - sagitta - 1e-9 && r <= 0.05 + 1e-9,
                "a point at r = {r} is in one body only"
            );
        }
    }
    assert_eq!(mesh.len(), 6320);
    let v = mesh.volume0.iter().sum::<f64>();
    let exact = std::f64::consts::PI * 0.05 * 0.05 * 0.1;
    // the lattice of spacing 5 mm resolves the column's volume to 0.6 %
    assert!((v / exact - 1.0).abs() < 0.01, "{v} against {exact}");
}

/// A mesh with a triangle missing is refused by `check` and `run` with exit status 2, naming
/// the key and the count of open edges; nothing is written.
#[test]
fn a_mesh_with_a_hole_is_refused() {
    let dir = scratch_dir("open-mesh");
    // a tetrahedron without its fourth face
    let stl = "solid t\n\
        facet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 0.1 0 0\nvertex 0 0.1 0\nendloop\nendfacet\n\
        facet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0 0.1\nvertex 0.1 0 0\nendloop\nendfacet\n\
        facet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0.1 0\nvertex 0 0 0.1\nendloop\nendfacet\n\
        endsolid t\n";
    std::fs::write(dir.join("open.stl"), stl).unwrap();
    let deck = r#"
[simulation]
dimension = 3
end_time = 0.01
cfl = 0.5
gravity = [0.0, 0.0, -9.81]

[grid]
size = [0.2, 0.2, 0.2]
cell_size = 0.02

[[materials]]
name = "water"
density = 1000.0

[[bodies]]
material = "water"
shape = { type = "mesh", file = "open.stl" }
"#;
    std::fs::write(dir.join("deck.toml"), deck).unwrap();
    let (deck, out) = (dir.join("deck.toml"), dir.join("out"));
    let (deck, out) = (deck.to_str().unwrap(), out.to_str().unwrap());
    for args in [&["check", deck][..], &["run", deck, "-o", out][..]] {
        let cmd = args[0];
        let o = pmpm(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{cmd}: {err}");
        assert!(
            err.contains("bodies[0].shape.file: is not a closed surface: 3 open edges"),
            "{cmd}: {err}"
        );
        assert!(
            !std::path::Path::new(out).exists(),
            "{cmd} wrote its output directory"
        );
    }
}
