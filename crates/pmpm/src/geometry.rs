//! Solid geometry: the regions bodies are filled from. A shape is a primitive (box, sphere,
//! cylinder, capsule, half-space, polygon), a closed triangle mesh read from STL or OBJ, or a
//! union, difference or intersection of shapes, each optionally scaled, rotated and
//! translated. [`ShapeDeck`] is the deck's form; [`ShapeDeck::solid`] checks it and builds a
//! [`Solid`], whose [`Solid::contains`] is an exact inside test (no voxels): the particle
//! lattice keeps the points it accepts.
//!
//! Meshes are read by `stl_io` and `tobj` and queried by parry's triangle mesh, whose inside
//! test takes the angle-weighted pseudo-normal of the nearest feature (Baerentzen & Aanaes,
//! "Signed distance computation using the angle weighted pseudonormal", IEEE TVCG 11, 2005):
//! exact for a closed, consistently oriented mesh. So a mesh is refused unless every edge
//! belongs to exactly two triangles that run through it in opposite directions; one whose
//! triangles all face inwards is turned outside out.

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// Kind of a shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    /// Axis-aligned box `min`..`max` (before `rotate`).
    Box,
    /// Sphere (disc in 2D) of `center` and `radius`.
    Sphere,
    /// Cylinder of `radius` around the segment `from`..`to`, flat ends (in 2D the rectangle
    /// it shows from the side).
    Cylinder,
    /// The points within `radius` of the segment `from`..`to` (rounded ends).
    Capsule,
    /// The side of the plane through `point` that `normal` points away from: a slope's
    /// ground, a reservoir's water below a level.
    HalfSpace,
    /// A polygon `vertices` (2D); in 3D extruded over `extrude = [lo, hi]` along `axis`.
    Polygon,
    /// A closed triangle mesh from `file` (STL, binary or ASCII, or OBJ), 3D only.
    Mesh,
    /// The points in any of `shapes`.
    Union,
    /// The points in the first of `shapes` and in none of the others.
    Difference,
    /// The points in all of `shapes`.
    Intersection,
}

impl ShapeKind {
    fn name(self) -> &'static str {
        match self {
            Self::Box => "box",
            Self::Sphere => "sphere",
            Self::Cylinder => "cylinder",
            Self::Capsule => "capsule",
            Self::HalfSpace => "half_space",
            Self::Polygon => "polygon",
            Self::Mesh => "mesh",
            Self::Union => "union",
            Self::Difference => "difference",
            Self::Intersection => "intersection",
        }
    }
    /// The keys of the kind, besides `type` and the transforms.
    fn keys(self) -> &'static [&'static str] {
        match self {
            Self::Box => &["min", "max"],
            Self::Sphere => &["center", "radius"],
            Self::Cylinder | Self::Capsule => &["from", "to", "radius"],
            Self::HalfSpace => &["point", "normal"],
            Self::Polygon => &["vertices", "axis", "extrude"],
            Self::Mesh => &["file"],
            Self::Union | Self::Difference | Self::Intersection => &["shapes"],
        }
    }
}

/// One number or one per axis: `scale = 0.001` or `scale = [1.0, 2.0, 1.0]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Numbers {
    /// The same for every axis (a 2D rotation's one angle).
    One(f64),
    /// One per axis.
    Many(Vec<f64>),
}

/// A shape as the deck gives it: `{ type = "box", min = [...], max = [...] }`, and so on for
/// each [`ShapeKind`], with optional `scale`, `rotate` (degrees) and `translate`, applied in
/// that order about the shape's own origin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct ShapeDeck {
    #[serde(rename = "type")]
    pub kind: ShapeKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vertices: Option<Vec<Vec<f64>>>,
    /// Polygon in 3D: the axis it is extruded along, "x", "y" or "z" (default "z").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extrude: Option<Vec<f64>>,
    /// Mesh file, relative to the deck (validation writes it out in full).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shapes: Option<Vec<ShapeDeck>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<Numbers>,
    /// Degrees: one angle in 2D (counter-clockwise), three in 3D (about x, then y, then z).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotate: Option<Numbers>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translate: Option<Vec<f64>>,
}

/// What is wrong with a shape: the key below the shape's own (`.radius`, `.shapes[1].file`)
/// and why.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeError {
    /// Path below the shape, starting with a dot; empty for the shape itself.
    pub key: String,
    /// What is wrong and what to do.
    pub message: String,
}

fn err<T>(key: impl Into<String>, message: impl Into<String>) -> Result<T, ShapeError> {
    Err(ShapeError {
        key: key.into(),
        message: message.into(),
    })
}

impl ShapeDeck {
    /// An axis-aligned box, as the programs that build decks write one.
    pub fn cuboid(min: Vec<f64>, max: Vec<f64>) -> Self {
        Self {
            min: Some(min),
            max: Some(max),
            ..Self::empty(ShapeKind::Box)
        }
    }

    /// A shape of `kind` with no keys set.
    pub fn empty(kind: ShapeKind) -> Self {
        Self {
            kind,
            min: None,
            max: None,
            center: None,
            radius: None,
            from: None,
            to: None,
            point: None,
            normal: None,
            vertices: None,
            axis: None,
            extrude: None,
            file: None,
            shapes: None,
            scale: None,
            rotate: None,
            translate: None,
        }
    }

    /// Whether the shape is a plain box (no rotation): what rigid bodies accept.
    pub fn is_plain_box(&self) -> bool {
        self.kind == ShapeKind::Box
            && self.rotate.is_none()
            && self.scale.is_none()
            && self.translate.is_none()
    }

    /// Writes every mesh file's path out in full, read against `dir` (the deck's folder), so
    /// that the run's own deck (`run.toml`) finds it from anywhere.
    pub fn resolve_files(&mut self, dir: &Path) {
        if let Some(f) = &mut self.file {
            let p = dir.join(&*f);
            *f = std::fs::canonicalize(&p)
                .unwrap_or(p)
                .to_string_lossy()
                .into_owned();
        }
        for s in self.shapes.iter_mut().flatten() {
            s.resolve_files(dir);
        }
    }

    /// Checks the shape in `dim` dimensions and builds it (reading any mesh file).
    pub fn solid(&self, dim: usize) -> Result<Solid, ShapeError> {
        self.keys_of_kind()?;
        let vector = |name: &str, v: &Option<Vec<f64>>| -> Result<Vector3<f64>, ShapeError> {
            let Some(v) = v else {
                return err(
                    format!(".{name}"),
                    format!("is required for type = \"{}\"", self.kind.name()),
                );
            };
            point(name, v, dim)
        };
        let positive = |name: &str, r: Option<f64>| -> Result<f64, ShapeError> {
            match r {
                None => err(
                    format!(".{name}"),
                    format!("is required for type = \"{}\"", self.kind.name()),
                ),
                Some(r) if !(r.is_finite() && r > 0.0) => {
                    err(format!(".{name}"), format!("must be > 0, got {r}"))
                }
                Some(r) => Ok(r),
            }
        };
        let prim = match self.kind {
            ShapeKind::Box => {
                let (lo, hi) = (vector("min", &self.min)?, vector("max", &self.max)?);
                if let Some(d) = (0..dim).find(|&d| lo[d] >= hi[d]) {
                    return err(
                        ".max",
                        format!(
                            "must exceed min in every direction: max[{d}] = {} <= min[{d}] = {}",
                            hi[d], lo[d]
                        ),
                    );
                }
                Prim::Box { lo, hi }
            }
            ShapeKind::Sphere => Prim::Sphere {
                center: vector("center", &self.center)?,
                radius: positive("radius", self.radius)?,
            },
            ShapeKind::Cylinder | ShapeKind::Capsule => {
                let (a, b) = (vector("from", &self.from)?, vector("to", &self.to)?);
                if (b - a).norm() == 0.0 {
                    return err(".to", "must differ from `from`: the axis has no length");
                }
                Prim::Segment {
                    a,
                    b,
                    radius: positive("radius", self.radius)?,
                    flat: self.kind == ShapeKind::Cylinder,
                }
            }
            ShapeKind::HalfSpace => {
                let p = vector("point", &self.point)?;
                let n = vector("normal", &self.normal)?;
                if n.norm() == 0.0 {
                    return err(".normal", "must not be zero");
                }
                Prim::HalfSpace {
                    point: p,
                    normal: n.normalize(),
                }
            }
            ShapeKind::Polygon => self.polygon(dim)?,
            ShapeKind::Mesh => {
                if dim != 3 {
                    return err(
                        "",
                        "a mesh is three-dimensional: with dimension = 2 use type = \"polygon\"",
                    );
                }
                let Some(file) = &self.file else {
                    return err(".file", "is required for type = \"mesh\"");
                };
                Prim::Mesh(Arc::new(Mesh::load(Path::new(file)).map_err(|m| {
                    ShapeError {
                        key: ".file".into(),
                        message: m,
                    }
                })?))
            }
            ShapeKind::Union | ShapeKind::Difference | ShapeKind::Intersection => {
                let Some(list) = &self.shapes else {
                    return err(
                        ".shapes",
                        format!("is required for type = \"{}\"", self.kind.name()),
                    );
                };
                if list.len() < 2 {
                    return err(
                        ".shapes",
                        format!("needs at least two shapes, got {}", list.len()),
                    );
                }
                let parts = list
                    .iter()
                    .enumerate()
                    .map(|(i, s)| {
                        s.solid(dim).map_err(|e| ShapeError {
                            key: format!(".shapes[{i}]{}", e.key),
                            message: e.message,
                        })
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                match self.kind {
                    ShapeKind::Union => Prim::Union(parts),
                    ShapeKind::Difference => Prim::Difference(parts),
                    _ => Prim::Intersection(parts),
                }
            }
        };
        self.sized(Solid {
            prim,
            transform: None,
            dim,
        })
    }

    /// The shape `own`, built without its transform, with it, refused when it is too small or
    /// too large to be a body's ([`Solid::size_problem`]): by the file or the shape's keys
    /// when it is so as the deck gives it, by `scale` or `translate` when the transform makes
    /// it so.
    fn sized(&self, own: Solid) -> Result<Solid, ShapeError> {
        let dim = own.dim;
        let sets = matches!(
            self.kind,
            ShapeKind::Union | ShapeKind::Difference | ShapeKind::Intersection
        );
        // a set's parts are checked on their own (and an intersection may be empty)
        if !sets {
            if let Some(why) = own.size_problem() {
                let key = if self.kind == ShapeKind::Mesh {
                    ".file"
                } else {
                    ""
                };
                return err(key, format!("the shape {why}"));
            }
        }
        let transform = self.transform(dim)?;
        let solid = Solid { transform, ..own };
        if let (Some(t), Some(why)) = (&solid.transform, solid.size_problem()) {
            // what the transform did: scaled the shape to nothing or past all bounds, or
            // moved it far away
            let far = t.shift.iter().any(|x| x.abs() > FAR / 2.0);
            let key = if far || self.scale.is_none() {
                ".translate"
            } else {
                ".scale"
            };
            return err(
                key,
                format!("makes a shape that {why}: a slip (a file in mm takes scale = 0.001)"),
            );
        }
        Ok(solid)
    }

    /// The keys set that the kind does not take.
    fn keys_of_kind(&self) -> Result<(), ShapeError> {
        let set = [
            ("min", self.min.is_some()),
            ("max", self.max.is_some()),
            ("center", self.center.is_some()),
            ("radius", self.radius.is_some()),
            ("from", self.from.is_some()),
            ("to", self.to.is_some()),
            ("point", self.point.is_some()),
            ("normal", self.normal.is_some()),
            ("vertices", self.vertices.is_some()),
            ("axis", self.axis.is_some()),
            ("extrude", self.extrude.is_some()),
            ("file", self.file.is_some()),
            ("shapes", self.shapes.is_some()),
        ];
        let takes = self.kind.keys();
        if let Some((k, _)) = set.iter().find(|(k, on)| *on && !takes.contains(k)) {
            return err(
                format!(".{k}"),
                format!(
                    "is not a key of type = \"{}\", which takes {} (and scale, rotate, translate)",
                    self.kind.name(),
                    takes.join(", ")
                ),
            );
        }
        Ok(())
    }

    fn polygon(&self, dim: usize) -> Result<Prim, ShapeError> {
        let Some(vs) = &self.vertices else {
            return err(".vertices", "is required for type = \"polygon\"");
        };
        if vs.len() < 3 {
            return err(
                ".vertices",
                format!("needs at least 3 points, got {}", vs.len()),
            );
        }
        let mut pts = Vec::with_capacity(vs.len());
        for (i, v) in vs.iter().enumerate() {
            if v.len() != 2 || !v.iter().all(|x| x.is_finite()) {
                return err(
                    format!(".vertices[{i}]"),
                    format!("must be two finite numbers (the polygon's plane), got {v:?}"),
                );
            }
            pts.push([v[0], v[1]]);
        }
        let area: f64 = (0..pts.len())
            .map(|i| {
                let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
                a[0] * b[1] - b[0] * a[1]
            })
            .sum();
        if area == 0.0 {
            return err(".vertices", "enclose no area");
        }
        let (normal, range) = if dim == 2 {
            if self.axis.is_some() || self.extrude.is_some() {
                return err(
                    ".extrude",
                    "is for dimension = 3 (a 2D polygon is the body's section)",
                );
            }
            (2, (f64::NEG_INFINITY, f64::INFINITY))
        } else {
            let axis = match self.axis.as_deref() {
                None | Some("z") => 2,
                Some("x") => 0,
                Some("y") => 1,
                Some(a) => {
                    return err(
                        ".axis",
                        format!("must be \"x\", \"y\" or \"z\", got \"{a}\""),
                    )
                }
            };
            let Some(e) = &self.extrude else {
                return err(
                    ".extrude",
                    "is required in 3D: [lo, hi], the polygon's extent along its axis",
                );
            };
            if e.len() != 2 || !e.iter().all(|x| x.is_finite()) || e[1] <= e[0] {
                return err(
                    ".extrude",
                    format!("must be [lo, hi] with hi > lo, got {e:?}"),
                );
            }
            (axis, (e[0], e[1]))
        };
        Ok(Prim::Polygon {
            points: pts,
            normal,
            range,
        })
    }

    /// x = t + R S y for a point y in the shape's own coordinates, as (R S, t).
    fn transform(&self, dim: usize) -> Result<Option<Affine>, ShapeError> {
        if self.scale.is_none() && self.rotate.is_none() && self.translate.is_none() {
            return Ok(None);
        }
        let mut scale = Vector3::new(1.0, 1.0, 1.0);
        match &self.scale {
            None => {}
            Some(Numbers::One(s)) => scale.fill(*s),
            Some(Numbers::Many(v)) => {
                if v.len() != dim {
                    return err(
                        ".scale",
                        format!(
                            "must be one number or {dim} (dimension = {dim}), got {}",
                            v.len()
                        ),
                    );
                }
                scale.rows_mut(0, dim).copy_from_slice(v);
            }
        }
        if let Some(s) = scale.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return err(".scale", format!("must be > 0, got {s}"));
        }
        let angles: Vector3<f64> = match (&self.rotate, dim) {
            (None, _) => Vector3::zeros(),
            (Some(Numbers::One(a)), 2) => Vector3::new(0.0, 0.0, *a),
            (Some(Numbers::Many(v)), 3) if v.len() == 3 => Vector3::new(v[0], v[1], v[2]),
            (Some(_), 2) => return err(".rotate", "in 2D is one angle in degrees (counter-clockwise)"),
            (Some(_), _) => {
                return err(
                    ".rotate",
                    "in 3D is three angles in degrees, [about x, about y, about z], applied in that order",
                )
            }
        };
        if let Some(a) = angles.iter().find(|a| !a.is_finite()) {
            return err(".rotate", format!("angles must be finite, got {a}"));
        }
        let r = Rotation3::from_axis_angle(&Vector3::z_axis(), angles[2].to_radians())
            * Rotation3::from_axis_angle(&Vector3::y_axis(), angles[1].to_radians())
            * Rotation3::from_axis_angle(&Vector3::x_axis(), angles[0].to_radians());
        let t = match &self.translate {
            None => Vector3::zeros(),
            Some(v) => point("translate", v, dim)?,
        };
        let linear = r.matrix() * Matrix3::from_diagonal(&scale);
        // (R S)^-1 = S^-1 R^T, built as such: no determinant to underflow
        let inverse = Matrix3::from_diagonal(&scale.map(|s| 1.0 / s)) * r.matrix().transpose();
        Ok(Some(Affine {
            linear,
            inverse,
            shift: t,
        }))
    }
}

/// The least extent of a shape along an axis (m): a body thinner than a nanometre is a slip
/// (a scale of 1e-300), and below it the lattices over a shape have no points.
pub const THIN: f64 = 1e-9;
/// The farthest a shape may reach from the origin (m): a million kilometres, past any deck,
/// and short of where the lattices over a shape lose their spacing to round-off.
pub const FAR: f64 = 1e9;

/// A deck point of `dim` finite components, as a 3-vector (z = 0 in 2D).
fn point(name: &str, v: &[f64], dim: usize) -> Result<Vector3<f64>, ShapeError> {
    if v.len() != dim {
        return err(
            format!(".{name}"),
            format!(
                "must have {dim} components (dimension = {dim}), got {}",
                v.len()
            ),
        );
    }
    if let Some(x) = v.iter().find(|x| !x.is_finite()) {
        return err(
            format!(".{name}"),
            format!("components must be finite, got {x}"),
        );
    }
    let mut p = Vector3::zeros();
    p.rows_mut(0, dim).copy_from_slice(v);
    Ok(p)
}

#[derive(Debug, Clone)]
struct Affine {
    linear: Matrix3<f64>,
    inverse: Matrix3<f64>,
    shift: Vector3<f64>,
}

#[derive(Debug, Clone)]
enum Prim {
    Box {
        lo: Vector3<f64>,
        hi: Vector3<f64>,
    },
    Sphere {
        center: Vector3<f64>,
        radius: f64,
    },
    /// A cylinder (`flat`) or a capsule around the segment a..b.
    Segment {
        a: Vector3<f64>,
        b: Vector3<f64>,
        radius: f64,
        flat: bool,
    },
    HalfSpace {
        point: Vector3<f64>,
        normal: Vector3<f64>,
    },
    /// In the plane normal to axis `normal`, over `range` along it.
    Polygon {
        points: Vec<[f64; 2]>,
        normal: usize,
        range: (f64, f64),
    },
    Mesh(Arc<Mesh>),
    Union(Vec<Solid>),
    Difference(Vec<Solid>),
    Intersection(Vec<Solid>),
}

/// A checked shape: an exact inside test and a bounding box.
#[derive(Debug, Clone)]
pub struct Solid {
    prim: Prim,
    transform: Option<Affine>,
    dim: usize,
}

impl Solid {
    /// Whether `x` (`dim` components) lies inside or on the shape.
    pub fn contains(&self, x: &[f64]) -> bool {
        let mut p = Vector3::zeros();
        p.rows_mut(0, self.dim).copy_from_slice(&x[..self.dim]);
        self.contains3(&p)
    }

    fn contains3(&self, x: &Vector3<f64>) -> bool {
        let y = match &self.transform {
            None => *x,
            Some(a) => a.inverse * (x - a.shift),
        };
        let dim = self.dim;
        match &self.prim {
            Prim::Box { lo, hi } => (0..dim).all(|d| y[d] >= lo[d] && y[d] <= hi[d]),
            Prim::Sphere { center, radius } => (y - center).norm_squared() <= radius * radius,
            Prim::Segment { a, b, radius, flat } => {
                let axis = b - a;
                let s = (y - a).dot(&axis) / axis.norm_squared();
                if *flat && !(0.0..=1.0).contains(&s) {
                    return false;
                }
                let nearest = a + axis * s.clamp(0.0, 1.0);
                (y - nearest).norm_squared() <= radius * radius
            }
            Prim::HalfSpace { point, normal } => (y - point).dot(normal) <= 0.0,
            Prim::Polygon {
                points,
                normal,
                range,
            } => {
                let (u, v) = match normal {
                    0 => (1, 2),
                    1 => (0, 2),
                    _ => (0, 1),
                };
                (range.0..=range.1).contains(&y[*normal]) && in_polygon(points, y[u], y[v])
            }
            Prim::Mesh(m) => m.contains(&y),
            Prim::Union(parts) => parts.iter().any(|s| s.contains3(&y)),
            Prim::Difference(parts) => {
                parts[0].contains3(&y) && !parts[1..].iter().any(|s| s.contains3(&y))
            }
            Prim::Intersection(parts) => parts.iter().all(|s| s.contains3(&y)),
        }
    }

    /// The shape's volume (area in 2D) in closed form, where it has one: the primitives and a
    /// mesh, under any transform (times |det| of its linear part); None for a half-space and
    /// the combinations, whose volume takes an integration.
    pub fn volume(&self) -> Option<f64> {
        use std::f64::consts::PI;
        let dim = self.dim;
        let v = match &self.prim {
            Prim::Box { lo, hi } => (0..dim).map(|d| hi[d] - lo[d]).product(),
            Prim::Sphere { radius: r, .. } if dim == 2 => PI * r * r,
            Prim::Sphere { radius: r, .. } => 4.0 / 3.0 * PI * r * r * r,
            Prim::Segment {
                a,
                b,
                radius: r,
                flat,
            } => {
                let l = (b - a).norm();
                match (dim, flat) {
                    (2, true) => 2.0 * r * l,
                    (2, false) => 2.0 * r * l + PI * r * r,
                    (_, true) => PI * r * r * l,
                    (_, false) => PI * r * r * l + 4.0 / 3.0 * PI * r * r * r,
                }
            }
            Prim::Polygon { points, range, .. } => {
                // the shoelace formula, times the extrusion in 3D
                let n = points.len();
                let twice: f64 = (0..n)
                    .map(|i| {
                        let (p, q) = (points[i], points[(i + 1) % n]);
                        p[0] * q[1] - q[0] * p[1]
                    })
                    .sum();
                let area = 0.5 * twice.abs();
                if dim == 2 {
                    area
                } else {
                    area * (range.1 - range.0)
                }
            }
            Prim::Mesh(m) => m.volume,
            Prim::HalfSpace { .. }
            | Prim::Union(_)
            | Prim::Difference(_)
            | Prim::Intersection(_) => return None,
        };
        let det = match &self.transform {
            None => 1.0,
            Some(a) if dim == 2 => a.linear.fixed_view::<2, 2>(0, 0).determinant(),
            Some(a) => a.linear.determinant(),
        };
        Some(v * det.abs())
    }

    /// The meshes the shape holds, in the order the deck gives them.
    pub fn meshes(&self) -> Box<dyn Iterator<Item = &Mesh> + '_> {
        match &self.prim {
            Prim::Mesh(m) => Box::new(std::iter::once(&**m)),
            Prim::Union(parts) | Prim::Difference(parts) | Prim::Intersection(parts) => {
                Box::new(parts.iter().flat_map(Solid::meshes))
            }
            _ => Box::new(std::iter::empty()),
        }
    }

    /// The files of the meshes the shape holds.
    pub fn mesh_sources(&self) -> impl Iterator<Item = &MeshSource> + '_ {
        self.meshes().filter_map(|m| m.source.as_ref())
    }

    /// Why the shape is too small or too large to be a body's (its extent along an axis under
    /// [`THIN`], or a point past [`FAR`]), if it is. Beyond these a lattice over it has no
    /// points or no end: a mesh scaled by 1e-300 kept `check` looping, one scaled by 1e300 took
    /// all memory.
    fn size_problem(&self) -> Option<String> {
        let (lo, hi) = self.bounds3();
        if (0..self.dim).any(|d| lo[d] > hi[d]) {
            // an empty intersection: no size to judge
            return None;
        }
        (0..self.dim).find_map(|d| {
            let axis = ["x", "y", "z"][d];
            let ext = hi[d] - lo[d];
            let far = [lo[d], hi[d]]
                .into_iter()
                .find(|x| x.is_finite() && x.abs() > FAR);
            if let Some(x) = far {
                Some(format!(
                    "reaches {x:e} m along {axis}, past {FAR:e} m from the origin"
                ))
            } else if ext.is_nan() || ext < THIN {
                Some(format!(
                    "is {ext:e} m across along {axis}, under {THIN:e} m"
                ))
            } else {
                None
            }
        })
    }

    /// A point inside both this shape and `other`, within the box `within` (lower, upper
    /// corner), if they overlap: tested on a lattice of 9^D points over the common part of
    /// their bounds and the box (shapes that only touch do not overlap).
    pub fn common_point(&self, other: &Solid, within: (&[f64], &[f64])) -> Option<Vec<f64>> {
        let dim = self.dim;
        let (alo, ahi) = self.bounds();
        let (blo, bhi) = other.bounds();
        let lo: Vec<f64> = (0..dim)
            .map(|d| alo[d].max(blo[d]).max(within.0[d]))
            .collect();
        let hi: Vec<f64> = (0..dim)
            .map(|d| ahi[d].min(bhi[d]).min(within.1[d]))
            .collect();
        if (0..dim).any(|d| hi[d] <= lo[d] || hi[d].is_nan() || lo[d].is_nan()) {
            return None;
        }
        let n = 9usize;
        (0..n.pow(dim as u32)).find_map(|k| {
            let x: Vec<f64> = (0..dim)
                .map(|d| {
                    let i = (k / n.pow(d as u32)) % n;
                    lo[d] + (hi[d] - lo[d]) * (i as f64 + 0.5) / n as f64
                })
                .collect();
            (self.contains(&x) && other.contains(&x)).then_some(x)
        })
    }

    /// A box (lower, upper corner; `dim` components) holding the shape; infinite along the
    /// axes where the shape is unbounded (a half-space).
    pub fn bounds(&self) -> (Vec<f64>, Vec<f64>) {
        let (lo, hi) = self.bounds3();
        (
            lo.as_slice()[..self.dim].to_vec(),
            hi.as_slice()[..self.dim].to_vec(),
        )
    }

    fn bounds3(&self) -> (Vector3<f64>, Vector3<f64>) {
        let inf = Vector3::repeat(f64::INFINITY);
        let (lo, hi) = match &self.prim {
            Prim::Box { lo, hi } => (*lo, *hi),
            Prim::Sphere { center, radius } => {
                (center.add_scalar(-radius), center.add_scalar(*radius))
            }
            Prim::Segment { a, b, radius, flat } => {
                // a flat end is a disc normal to the axis: along axis d it reaches
                // r sqrt(1 - e_d^2) past its centre, e the unit axis (a capsule's ball, r)
                let e = (b - a).normalize();
                let reach = Vector3::from_fn(|d, _| {
                    if *flat {
                        radius * (1.0 - e[d] * e[d]).max(0.0).sqrt()
                    } else {
                        *radius
                    }
                });
                (a.inf(b) - reach, a.sup(b) + reach)
            }
            Prim::HalfSpace { point, normal } => {
                // bounded only along an axis the plane is normal to
                let (mut lo, mut hi) = (-inf, inf);
                for d in 0..3 {
                    if normal[d].abs() == 1.0 {
                        if normal[d] > 0.0 {
                            hi[d] = point[d];
                        } else {
                            lo[d] = point[d];
                        }
                    }
                }
                (lo, hi)
            }
            Prim::Polygon {
                points,
                normal,
                range,
            } => {
                let (u, v) = match normal {
                    0 => (1, 2),
                    1 => (0, 2),
                    _ => (0, 1),
                };
                let (mut lo, mut hi) = (-inf, inf);
                for (k, axis) in [u, v].into_iter().enumerate() {
                    lo[axis] = points.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
                    hi[axis] = points
                        .iter()
                        .map(|p| p[k])
                        .fold(f64::NEG_INFINITY, f64::max);
                }
                (lo[*normal], hi[*normal]) = *range;
                (lo, hi)
            }
            Prim::Mesh(m) => (m.lo, m.hi),
            Prim::Union(parts) => parts
                .iter()
                .map(Solid::bounds3)
                .fold((inf, -inf), |(lo, hi), (a, b)| (lo.inf(&a), hi.sup(&b))),
            Prim::Difference(parts) => parts[0].bounds3(),
            Prim::Intersection(parts) => parts
                .iter()
                .map(Solid::bounds3)
                .fold((-inf, inf), |(lo, hi), (a, b)| (lo.sup(&a), hi.inf(&b))),
        };
        let (mut lo, mut hi) = (lo, hi);
        if self.dim == 2 {
            (lo[2], hi[2]) = (0.0, 0.0);
        }
        let Some(a) = &self.transform else {
            return (lo, hi);
        };
        let (mut blo, mut bhi) = (inf, -inf);
        for d in 0..3 {
            let (x, y) = interval(&a.linear.row(d).transpose(), &lo, &hi);
            blo[d] = x + a.shift[d];
            bhi[d] = y + a.shift[d];
        }
        (blo, bhi)
    }
}

/// The range of row . y over the box lo..hi (finite where the row's nonzero entries are).
fn interval(row: &Vector3<f64>, lo: &Vector3<f64>, hi: &Vector3<f64>) -> (f64, f64) {
    let (mut a, mut b) = (0.0, 0.0);
    for e in 0..3 {
        if row[e] == 0.0 {
            continue;
        }
        let (p, q) = (row[e] * lo[e], row[e] * hi[e]);
        a += p.min(q);
        b += p.max(q);
    }
    (a, b)
}

/// Even-odd crossing test of the point (u, v) against a simple polygon.
// Written out: ten lines, where a crate would need the polygon built into its own shape type.
fn in_polygon(points: &[[f64; 2]], u: f64, v: f64) -> bool {
    let mut inside = false;
    let mut j = points.len() - 1;
    for i in 0..points.len() {
        let (a, b) = (points[i], points[j]);
        if (a[1] > v) != (b[1] > v) && u < (b[0] - a[0]) * (v - a[1]) / (b[1] - a[1]) + a[0] {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// A closed, outward-oriented triangle mesh.
pub struct Mesh {
    shape: parry3d_f64::shape::TriMesh,
    lo: Vector3<f64>,
    hi: Vector3<f64>,
    /// Enclosed volume (m3).
    pub volume: f64,
    /// Triangles.
    pub triangles: usize,
    /// The file it was read from.
    pub source: Option<MeshSource>,
}

impl std::fmt::Debug for Mesh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Mesh({} triangles)", self.triangles)
    }
}

impl Mesh {
    /// Reads an STL (binary or ASCII) or OBJ file and checks it is closed.
    pub fn load(path: &Path) -> Result<Mesh, String> {
        let (bytes, source) = read_mesh_file(path)?;
        let (vertices, triangles) = read_triangles(path, bytes)?;
        let mut mesh = Mesh::new(vertices, triangles)?;
        mesh.source = Some(source);
        Ok(mesh)
    }

    /// The mesh of `triangles` over `vertices`, welded where vertices coincide, checked to be
    /// closed and oriented, and turned outside out if every triangle faces inwards.
    pub fn new(vertices: Vec<[f64; 3]>, triangles: Vec<[usize; 3]>) -> Result<Mesh, String> {
        if triangles.is_empty() {
            return Err("holds no triangles".into());
        }
        if let Some(v) = vertices.iter().find(|v| !v.iter().all(|x| x.is_finite())) {
            return Err(format!("has a vertex that is not finite: {v:?}"));
        }
        // weld coincident vertices: a file may repeat each vertex per triangle (STL always
        // does; stl_io merges exact repeats, OBJ exports may not)
        let mut index: HashMap<[u64; 3], u32> = HashMap::new();
        let mut points: Vec<Vector3<f64>> = Vec::new();
        let remap: Vec<u32> = vertices
            .iter()
            .map(|v| {
                // + 0.0 makes -0.0 and 0.0 one point
                *index
                    .entry(v.map(|c| (c + 0.0).to_bits()))
                    .or_insert_with(|| {
                        points.push(Vector3::from(*v));
                        (points.len() - 1) as u32
                    })
            })
            .collect();
        let mut tris: Vec<[u32; 3]> = Vec::with_capacity(triangles.len());
        for t in &triangles {
            if let Some(&i) = t.iter().find(|&&i| i >= vertices.len()) {
                return Err(format!(
                    "a triangle names vertex {i}, but there are {}",
                    vertices.len()
                ));
            }
            let t = t.map(|i| remap[i]);
            // a triangle with two equal corners has no area and no edge pairs
            if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                tris.push(t);
            }
        }
        let (open, bad) = open_edges(&tris);
        if open > 0 || bad > 0 {
            return Err(format!(
                "is not a closed surface: {open} open edges (edges of one triangle only){}; a body needs a watertight mesh (close the holes in the CAD program or a mesh repair tool)",
                if bad > 0 {
                    format!(
                        " and {bad} edges shared by more than two triangles or by two that face opposite ways"
                    )
                } else {
                    String::new()
                }
            ));
        }
        let volume: f64 = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| points[i as usize]);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum();
        if volume == 0.0 {
            return Err("encloses no volume".into());
        }
        if volume < 0.0 {
            for t in &mut tris {
                t.swap(1, 2);
            }
        }
        let (lo, hi) = points.iter().fold(
            (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ),
            |(lo, hi), p| (lo.inf(p), hi.sup(p)),
        );
        let verts: Vec<parry3d_f64::math::Vector> = points
            .iter()
            .map(|p| parry3d_f64::math::Vector::new(p.x, p.y, p.z))
            .collect();
        let count = tris.len();
        let shape = parry3d_f64::shape::TriMesh::with_flags(
            verts,
            tris,
            parry3d_f64::shape::TriMeshFlags::ORIENTED,
        )
        .map_err(|e| format!("cannot be used: {e}"))?;
        Ok(Mesh {
            shape,
            lo,
            hi,
            volume: volume.abs(),
            triangles: count,
            source: None,
        })
    }

    /// Whether `y` lies inside or on the mesh: by the first crossing of a ray from it, which
    /// leaves through a triangle's back (its outward normal along the ray) from inside. A ray
    /// cast walks parry's tree down to that one crossing. parry's own test finds the nearest
    /// point of the surface, and deep in a round body every triangle is about as near: the
    /// search visited them all (100k triangles: 114 s for `check` of a ball's deck, against
    /// 10 s with the ray). A ray that meets the surface at a grazing angle or at a triangle's
    /// edge or corner (where the triangle it reports may face either way) falls back on
    /// parry's nearest-point test, exact for a closed mesh.
    fn contains(&self, y: &Vector3<f64>) -> bool {
        use parry3d_f64::math::Vector;
        use parry3d_f64::query::{PointQuery, Ray, RayCast};
        if !(0..3).all(|d| y[d] >= self.lo[d] && y[d] <= self.hi[d]) {
            return false;
        }
        let p = Vector::new(y.x, y.y, y.z);
        // a direction along no axis nor any simple diagonal, which the edges of a CAD part's
        // faces follow
        let dir = Vector::new(
            0.302_775_637_731_995,
            0.555_111_512_312_578,
            0.774_596_669_241_483,
        )
        .normalize();
        let Some(hit) =
            self.shape
                .cast_local_ray_and_get_normal(&Ray::new(p, dir), f64::MAX, false)
        else {
            return false;
        };
        if hit.time_of_impact == 0.0 {
            return true;
        }
        let tri = self.shape.triangle(hit.subshape);
        let n = tri.scaled_normal();
        let along = n.dot(dir) / n.length();
        // the crossing's barycentric coordinates: one near 0 is an edge or a corner
        let q = p + dir * hit.time_of_impact;
        let area = n.length_squared();
        let inner = [
            (tri.b - q).cross(tri.c - q).dot(n) / area,
            (tri.c - q).cross(tri.a - q).dot(n) / area,
            (tri.a - q).cross(tri.b - q).dot(n) / area,
        ];
        if along.abs() > 1e-6 && inner.iter().all(|&w| w > 1e-9) {
            along > 0.0
        } else {
            self.shape.contains_local_point(p)
        }
    }
}

/// Edges of one triangle only, and edges of more than two or of two in the same direction.
fn open_edges(tris: &[[u32; 3]]) -> (usize, usize) {
    // per undirected edge: the uses in each direction
    let mut uses: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = uses.entry((a.min(b), a.max(b))).or_default();
            if a < b {
                e.0 += 1;
            } else {
                e.1 += 1;
            }
        }
    }
    let open = uses.values().filter(|(f, b)| f + b == 1).count();
    let bad = uses
        .values()
        .filter(|(f, b)| f + b > 1 && !(*f == 1 && *b == 1))
        .count();
    (open, bad)
}

/// Vertices, and triangles as three vertex indices.
type Triangles = (Vec<[f64; 3]>, Vec<[usize; 3]>);

/// A mesh file's identity: its path, its length and the CRC-32 of its bytes, recorded with a
/// run so that a resume from a file changed since is refused.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct MeshSource {
    /// The path as the deck holds it (in full once the deck is checked).
    pub path: String,
    /// Length in bytes.
    pub bytes: u64,
    /// CRC-32 of the bytes.
    pub crc32: u32,
}

impl MeshSource {
    /// `"<bytes> bytes, crc32 <hex>"`, as the run's record holds it.
    pub fn digest(&self) -> String {
        format!("{} bytes, crc32 {:08x}", self.bytes, self.crc32)
    }
}

/// The bytes of the mesh file `path`, refused unless it is a regular file (after following
/// links): opening a FIFO or a device would wait for a writer or read for ever.
fn read_mesh_file(path: &Path) -> Result<(Vec<u8>, MeshSource), String> {
    let shown = path.display();
    let meta = std::fs::metadata(path).map_err(|e| format!("cannot read {shown}: {e}"))?;
    if !meta.is_file() {
        let what = if meta.is_dir() {
            "a directory"
        } else {
            "not a regular file (a FIFO, a socket or a device)"
        };
        return Err(format!(
            "{shown} is {what}: give a mesh file (.stl or .obj)"
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {shown}: {e}"))?;
    let source = MeshSource {
        path: path.to_string_lossy().into_owned(),
        bytes: bytes.len() as u64,
        crc32: crc32fast::hash(&bytes),
    };
    Ok((bytes, source))
}

/// Whether `bytes` are a binary STL file: an 80-byte header, a triangle count n, and n records
/// of 50 bytes, to the byte. CAD programs often begin the header with `solid `, which the
/// ASCII format begins with too, so the length decides, not the first word.
fn is_binary_stl(bytes: &[u8]) -> bool {
    let Some(count) = bytes.get(80..84) else {
        return false;
    };
    let n = u32::from_le_bytes([count[0], count[1], count[2], count[3]]) as u64;
    bytes.len() as u64 == 84 + 50 * n
}

/// The vertices and triangles of the STL or OBJ file `bytes` read from `path`, by its
/// extension.
fn read_triangles(path: &Path, mut bytes: Vec<u8>) -> Result<Triangles, String> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let shown = path.display();
    match ext.as_str() {
        "stl" => {
            if is_binary_stl(&bytes) {
                // stl_io takes a file beginning with `solid ` for ASCII: blank the header,
                // which holds nothing the mesh needs
                bytes[..80].fill(0);
            }
            let m = stl_io::read_stl(&mut std::io::Cursor::new(bytes))
                .map_err(|e| format!("{shown} is not a readable STL file: {e}"))?;
            Ok((
                m.vertices
                    .iter()
                    .map(|v| [v[0] as f64, v[1] as f64, v[2] as f64])
                    .collect(),
                m.faces.iter().map(|t| t.vertices).collect(),
            ))
        }
        "obj" => {
            let opts = tobj::LoadOptions {
                triangulate: true,
                single_index: true,
                ..Default::default()
            };
            // materials are not read: a body takes its material from the deck
            let (models, _) = tobj::load_obj_buf(&mut std::io::Cursor::new(bytes), &opts, |_| {
                Err(tobj::LoadError::OpenFileFailed)
            })
            .map_err(|e| format!("{shown} is not a readable OBJ file: {e}"))?;
            let (mut vs, mut ts) = (Vec::new(), Vec::new());
            for m in models {
                let base = vs.len();
                vs.extend(
                    m.mesh
                        .positions
                        .chunks_exact(3)
                        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]),
                );
                ts.extend(m.mesh.indices.chunks_exact(3).map(|t| {
                    [
                        base + t[0] as usize,
                        base + t[1] as usize,
                        base + t[2] as usize,
                    ]
                }));
            }
            Ok((vs, ts))
        }
        _ => Err(format!(
            "{shown}: the mesh format is read from the extension, .stl or .obj"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(src: &str) -> ShapeDeck {
        toml::from_str::<toml::Table>(&format!("s = {src}")).unwrap()["s"]
            .clone()
            .try_into()
            .unwrap()
    }

    fn solid(src: &str, dim: usize) -> Solid {
        parse(src).solid(dim).unwrap()
    }

    /// A cylinder of `n` sides around the z axis, radius r, z from 0 to height, outward.
    fn cylinder_mesh(n: usize, r: f64, height: f64) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
        let mut v = vec![[0.0, 0.0, 0.0], [0.0, 0.0, height]];
        for k in 0..n {
            let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            v.push([r * a.cos(), r * a.sin(), 0.0]);
            v.push([r * a.cos(), r * a.sin(), height]);
        }
        let mut t = Vec::new();
        for k in 0..n {
            let (b0, t0) = (2 + 2 * k, 3 + 2 * k);
            let (b1, t1) = (2 + 2 * ((k + 1) % n), 3 + 2 * ((k + 1) % n));
            t.push([0, b1, b0]);
            t.push([1, t0, t1]);
            t.push([b0, b1, t1]);
            t.push([b0, t1, t0]);
        }
        (v, t)
    }

    fn write_stl(path: &Path, v: &[[f64; 3]], t: &[[usize; 3]]) {
        let mut s = String::from("solid test\n");
        for tri in t {
            s += "facet normal 0 0 0\nouter loop\n";
            for &i in tri {
                s += &format!("vertex {} {} {}\n", v[i][0], v[i][1], v[i][2]);
            }
            s += "endloop\nendfacet\n";
        }
        s += "endsolid test\n";
        std::fs::write(path, s).unwrap();
    }

    #[test]
    fn primitives_hold_their_points() {
        let b = solid("{ type = \"box\", min = [0.0, 0.0], max = [1.0, 2.0] }", 2);
        assert!(b.contains(&[0.5, 1.9]) && !b.contains(&[1.1, 1.0]));
        let c = solid(
            "{ type = \"cylinder\", from = [0.0, 0.0, 0.0], to = [0.0, 0.0, 1.0], radius = 0.5 }",
            3,
        );
        assert!(c.contains(&[0.3, 0.3, 0.9]) && !c.contains(&[0.4, 0.4, 0.5]));
        assert!(!c.contains(&[0.0, 0.0, 1.1]));
        let k = solid(
            "{ type = \"capsule\", from = [0.0, 0.0], to = [1.0, 0.0], radius = 0.5 }",
            2,
        );
        assert!(k.contains(&[1.4, 0.0]) && !k.contains(&[1.4, 0.4]));
        let h = solid(
            "{ type = \"half_space\", point = [0.0, 1.0], normal = [1.0, 1.0] }",
            2,
        );
        assert!(h.contains(&[0.0, 0.9]) && !h.contains(&[0.5, 0.6]));
        let p = solid(
            "{ type = \"polygon\", vertices = [[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]] }",
            2,
        );
        assert!(p.contains(&[0.5, 0.5]) && !p.contains(&[1.5, 0.5]));
        let p3 = solid(
            "{ type = \"polygon\", vertices = [[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]], axis = \"y\", extrude = [0.0, 3.0] }",
            3,
        );
        // the vertices are (x, z) for axis = "y"
        assert!(p3.contains(&[0.5, 2.5, 0.5]) && !p3.contains(&[0.5, 3.5, 0.5]));
        assert!(!p3.contains(&[1.5, 1.0, 0.5]));
    }

    #[test]
    fn sets_and_transforms_combine_shapes() {
        // a tank's water: a box less a sphere, and a rotated box
        let d = solid(
            "{ type = \"difference\", shapes = [{ type = \"box\", min = [0.0, 0.0], max = [2.0, 1.0] }, { type = \"sphere\", center = [1.0, 0.0], radius = 0.5 }] }",
            2,
        );
        assert!(d.contains(&[0.2, 0.2]) && !d.contains(&[1.0, 0.2]));
        let r = solid(
            "{ type = \"box\", min = [0.0, 0.0], max = [2.0, 1.0], rotate = 90.0, translate = [5.0, 0.0] }",
            2,
        );
        // (x, y) -> (-y, x) + (5, 0): the box spans x in [4, 5], y in [0, 2]
        assert!(r.contains(&[4.5, 1.5]) && !r.contains(&[5.5, 0.5]));
        let (lo, hi) = r.bounds();
        for (a, b) in lo.iter().chain(&hi).zip([4.0, 0.0, 5.0, 2.0]) {
            assert!((a - b).abs() < 1e-12, "{lo:?} {hi:?}");
        }
        let i = solid(
            "{ type = \"intersection\", shapes = [{ type = \"half_space\", point = [0.0, 1.0], normal = [0.0, 1.0] }, { type = \"box\", min = [0.0, 0.0], max = [3.0, 3.0] }] }",
            2,
        );
        assert_eq!(i.bounds(), (vec![0.0, 0.0], vec![3.0, 1.0]));
        let s = solid(
            "{ type = \"sphere\", center = [0.0, 0.0, 0.0], radius = 1.0, scale = [2.0, 1.0, 1.0] }",
            3,
        );
        assert!(s.contains(&[1.9, 0.0, 0.0]) && !s.contains(&[0.0, 1.1, 0.0]));
    }

    #[test]
    fn bad_shapes_name_the_key() {
        let e = |src: &str, dim| parse(src).solid(dim).unwrap_err();
        let k = e(
            "{ type = \"sphere\", center = [0.0, 0.0], radius = 1.0, min = [0.0, 0.0] }",
            2,
        );
        assert_eq!(k.key, ".min");
        assert!(k.message.contains("center, radius"), "{}", k.message);
        let k = e("{ type = \"union\", shapes = [{ type = \"box\", min = [0.0, 0.0], max = [1.0, 1.0] }, { type = \"sphere\", center = [0.0, 0.0] }] }", 2);
        assert_eq!(k.key, ".shapes[1].radius");
        let k = e("{ type = \"mesh\", file = \"x.stl\" }", 2);
        assert!(k.message.contains("polygon"), "{}", k.message);
        let k = e(
            "{ type = \"box\", min = [0.0, 0.0], max = [1.0, 1.0], rotate = [1.0, 2.0, 3.0] }",
            2,
        );
        assert_eq!(k.key, ".rotate");
    }

    #[test]
    fn a_closed_mesh_is_inside_where_its_cylinder_is() {
        let (v, t) = cylinder_mesh(64, 0.5, 1.0);
        let m = Mesh::new(v.clone(), t.clone()).unwrap();
        // the polygon's area, (n/2) r^2 sin(2 pi / n), times the height
        let exact = 32.0 * 0.25 * (2.0 * std::f64::consts::PI / 64.0).sin();
        assert!((m.volume - exact).abs() < 1e-12 * exact, "{}", m.volume);
        let prim = solid(
            "{ type = \"cylinder\", from = [0.0, 0.0, 0.0], to = [0.0, 0.0, 1.0], radius = 0.5 }",
            3,
        );
        // on a lattice the mesh and the cylinder agree except within the 64-gon's sagitta,
        // r (1 - cos(pi / 64)) = 6e-4 r, of the curved face
        let (mut same, mut all) = (0, 0);
        for i in 0..24 {
            for j in 0..24 {
                for k in 0..12 {
                    let x = [
                        -0.6 + 1.2 * (i as f64 + 0.5) / 24.0,
                        -0.6 + 1.2 * (j as f64 + 0.5) / 24.0,
                        -0.1 + 1.2 * (k as f64 + 0.5) / 12.0,
                    ];
                    let y = Vector3::from(x);
                    let r = (x[0] * x[0] + x[1] * x[1]).sqrt();
                    if (r - 0.5).abs() < 1e-3 {
                        continue;
                    }
                    all += 1;
                    same += usize::from(m.contains(&y) == prim.contains(&x));
                }
            }
        }
        assert_eq!(same, all);
        // turned inside out, it is turned back
        let inward: Vec<[usize; 3]> = t.iter().map(|t| [t[0], t[2], t[1]]).collect();
        let m2 = Mesh::new(v.clone(), inward).unwrap();
        assert!(m2.contains(&Vector3::new(0.0, 0.0, 0.5)));
        assert!(!m2.contains(&Vector3::new(0.0, 0.0, 1.5)));
        // one triangle gone: three open edges
        let e = Mesh::new(v, t[1..].to_vec()).unwrap_err();
        assert!(e.contains("3 open edges"), "{e}");
    }

    /// A ball of `2 n^2` triangles of radius `r` about the origin, facing outwards.
    fn ball_mesh(n: usize, r: f64) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
        use std::f64::consts::PI;
        let mut v = vec![[0.0, 0.0, r], [0.0, 0.0, -r]];
        for i in 1..n {
            let th = PI * i as f64 / n as f64;
            for j in 0..n {
                let ph = 2.0 * PI * j as f64 / n as f64;
                v.push([
                    r * th.sin() * ph.cos(),
                    r * th.sin() * ph.sin(),
                    r * th.cos(),
                ]);
            }
        }
        let at = |i: usize, j: usize| match i {
            0 => 0,
            _ if i == n => 1,
            _ => 2 + (i - 1) * n + j % n,
        };
        let mut t = Vec::new();
        for i in 0..n {
            for j in 0..n {
                if i > 0 {
                    t.push([at(i, j), at(i + 1, j), at(i, j + 1)]);
                }
                if i + 1 < n {
                    t.push([at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
                }
            }
        }
        (v, t)
    }

    /// Points deep in a ball of 100k triangles are found inside at once, and every point of a
    /// lattice over it where the ball is: parry's nearest-point test visited every triangle
    /// for each point near the centre (a rigid ball's `check` took 114 s, 10 s with the ray).
    #[test]
    fn a_fine_mesh_answers_inside_deep_in_it_at_once() {
        let (v, t) = ball_mesh(224, 0.1);
        let m = Mesh::new(v, t).unwrap();
        assert!(m.triangles > 99_000, "{}", m.triangles);
        let start = std::time::Instant::now();
        let n = 16;
        let (mut inside, mut all) = (0, 0);
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let y = Vector3::from_fn(|d, _| {
                        let idx = [i, j, k][d] as f64;
                        -0.11 + 0.22 * (idx + 0.5) / n as f64
                    });
                    // off the faceted surface by more than its sagitta, r (1 - cos(pi / 224))
                    if (y.norm() - 0.1).abs() < 2e-4 {
                        continue;
                    }
                    all += 1;
                    inside += usize::from(m.contains(&y));
                    assert_eq!(m.contains(&y), y.norm() < 0.1, "{y}");
                }
            }
        }
        let took = start.elapsed().as_secs_f64();
        assert!(inside > 1000 && all > inside);
        assert!(took < 2.0, "{all} points took {took} s");
    }

    #[test]
    fn stl_and_obj_files_read_as_the_same_solid() {
        let dir = std::env::temp_dir().join(format!("pmpm-geometry-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (v, t) = cylinder_mesh(16, 0.5, 1.0);
        write_stl(&dir.join("c.stl"), &v, &t);
        let mut obj = String::new();
        for p in &v {
            obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        for f in &t {
            obj += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
        }
        std::fs::write(dir.join("c.obj"), obj).unwrap();
        for name in ["c.stl", "c.obj"] {
            let mut s = parse(&format!(
                "{{ type = \"mesh\", file = \"{name}\", scale = 2.0, translate = [1.0, 1.0, 0.0] }}"
            ));
            s.resolve_files(&dir);
            let m = s.solid(3).unwrap();
            assert!(m.contains(&[1.0, 1.0, 1.9]) && m.contains(&[1.9, 1.0, 0.1]));
            assert!(!m.contains(&[1.0, 1.0, 2.1]) && !m.contains(&[2.1, 1.0, 1.0]));
        }
        write_stl(&dir.join("open.stl"), &v, &t[2..]);
        let mut s = parse("{ type = \"mesh\", file = \"open.stl\" }");
        s.resolve_files(&dir);
        let e = s.solid(3).unwrap_err();
        assert_eq!(e.key, ".file");
        assert!(e.message.contains("6 open edges"), "{}", e.message);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
