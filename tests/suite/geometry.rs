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
    let deck = mesh_deck(r#"{ type = "mesh", file = "open.stl" }"#, "");
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

/// The triangles of the box `lo`..`hi`, facing outwards.
pub fn box_triangles(lo: [f32; 3], hi: [f32; 3]) -> Vec<[[f32; 3]; 3]> {
    let corner = |i: usize| -> [f32; 3] {
        std::array::from_fn(|d| if i >> d & 1 == 1 { hi[d] } else { lo[d] })
    };
    let faces = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    faces
        .iter()
        .flat_map(|[a, b, c, d]| {
            [
                [corner(*a), corner(*b), corner(*c)],
                [corner(*a), corner(*c), corner(*d)],
            ]
        })
        .collect()
}

/// Writes `triangles` as a binary STL file whose 80-byte header begins with `header`.
pub fn write_binary_stl(path: &std::path::Path, header: &str, triangles: &[[[f32; 3]; 3]]) {
    let mut bytes = header.as_bytes().to_vec();
    bytes.resize(80, b' ');
    bytes.extend((triangles.len() as u32).to_le_bytes());
    for t in triangles {
        bytes.extend([0u8; 12]);
        for v in t {
            for c in v {
                bytes.extend(c.to_le_bytes());
            }
        }
        bytes.extend([0u8; 2]);
    }
    std::fs::write(path, bytes).unwrap();
}

/// `pmpm` with `args`, killed after `seconds`: (exit status, stdout, stderr), the status None
/// when it was killed (a hang).
fn pmpm_within(args: &[&str], seconds: u64) -> (Option<i32>, String, String) {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_pmpm"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s.code();
        }
        if start.elapsed().as_secs() >= seconds {
            child.kill().unwrap();
            break None;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let o = child.wait_with_output().unwrap();
    (
        status,
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// A 3D deck of water shaped by `shape`, with the extra tables `extra`.
fn mesh_deck(shape: &str, extra: &str) -> String {
    format!(
        r#"
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
shape = {shape}
{extra}
"#
    )
}

/// A binary STL whose header begins with `solid ` (as CAD programs write it) is read as
/// binary: its length is 84 bytes and 50 per triangle, to the byte. It used to be taken for
/// ASCII and refused ("stream did not contain valid UTF-8"). `check`'s memory estimate counts
/// its triangles.
#[test]
fn a_binary_stl_whose_header_begins_with_solid_is_read() {
    let dir = scratch_dir("solid-header");
    let stl = dir.join("part.stl");
    write_binary_stl(
        &stl,
        "solid part\nexported by a CAD program",
        &box_triangles([0.02, 0.02, 0.02], [0.12, 0.12, 0.12]),
    );
    let deck = dir.join("deck.toml");
    std::fs::write(
        &deck,
        mesh_deck(r#"{ type = "mesh", file = "part.stl" }"#, ""),
    )
    .unwrap();
    let (status, out, err) = pmpm_within(&["check", deck.to_str().unwrap()], 60);
    assert_eq!(status, Some(0), "{err}");
    // a box of 5 x 5 x 5 cells at 2 particles per cell and direction
    assert!(out.contains("1000 particles"), "{out}");
    assert!(out.contains("B per mesh triangle (12 triangles)"), "{out}");
}

/// A transform that makes a shape absurdly small or large is refused naming its key, at once:
/// a mesh scaled by 1e-300 kept `check` looping for ever (a rigid body's volume lattice had a
/// spacing of zero) and one scaled by 1e300 took all memory (its surface rays).
#[test]
fn absurd_transforms_are_refused_naming_the_key() {
    let dir = scratch_dir("absurd-scale");
    write_binary_stl(
        &dir.join("part.stl"),
        "part",
        &box_triangles([0.0, 0.0, 0.0], [0.1, 0.1, 0.1]),
    );
    let cases = [
        (
            "scale = 1e-300",
            "rigid_bodies[0].shape.scale: makes a shape that is",
        ),
        (
            "scale = 1e300",
            "rigid_bodies[0].shape.scale: makes a shape that reaches",
        ),
        (
            "scale = [1.0, 1.0, 1e-20]",
            "m across along z, under 1e-9 m",
        ),
        (
            "translate = [1e12, 0.0, 0.0]",
            "rigid_bodies[0].shape.translate: makes a shape that reaches",
        ),
    ];
    for (transform, wanted) in cases {
        let rigid = format!(
            "[[rigid_bodies]]\nname = \"part\"\nshape = {{ type = \"mesh\", file = \"part.stl\", {transform} }}\n"
        );
        let deck = dir.join("deck.toml");
        std::fs::write(
            &deck,
            mesh_deck(
                r#"{ type = "box", min = [0.0, 0.0, 0.0], max = [0.2, 0.2, 0.05] }"#,
                &rigid,
            ),
        )
        .unwrap();
        let (status, _, err) = pmpm_within(&["check", deck.to_str().unwrap()], 30);
        assert_eq!(status, Some(2), "{transform}: {err}");
        assert!(err.contains(wanted), "{transform}: {err}");
    }
}

/// A mesh path that is a FIFO or a directory is refused naming the key and the path: opening
/// a FIFO waited for a writer for ever.
#[cfg(unix)]
#[test]
fn a_mesh_path_that_is_not_a_regular_file_is_refused() {
    let dir = scratch_dir("fifo-mesh");
    let fifo = dir.join("pipe.stl");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    std::fs::create_dir(dir.join("folder.stl")).unwrap();
    for (name, what) in [
        ("pipe.stl", "is not a regular file"),
        ("folder.stl", "is a directory"),
    ] {
        let deck = dir.join("deck.toml");
        let shape = format!("{{ type = \"mesh\", file = \"{name}\" }}");
        std::fs::write(&deck, mesh_deck(&shape, "")).unwrap();
        let (status, _, err) = pmpm_within(&["check", deck.to_str().unwrap()], 30);
        assert_eq!(status, Some(2), "{name}: {err}");
        let path = std::fs::canonicalize(dir.join(name)).unwrap();
        let wanted = format!("bodies[0].shape.file: {} {what}", path.display());
        assert!(err.contains(&wanted), "{name}: {err}");
    }
}
