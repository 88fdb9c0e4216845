//! Wall friction by the law of the wall: the shear a smooth wall puts on water that slides
//! along it, where the grid is far too coarse to resolve the boundary layer.
//!
//! A slip wall has no friction, a no-slip wall holds the node on it at rest: at the cell sizes
//! of a tank (millimetres to centimetres) both miss the real wall, whose turbulent boundary
//! layer is a fraction of a millimetre thick. Finite-volume codes bridge it with a wall
//! function (Launder & Spalding 1974, "The numerical computation of turbulent flows", Comput.
//! Methods Appl. Mech. Eng. 3): the wall shear tau_w follows from the velocity U sampled at a
//! distance y from the wall through the universal velocity profile. pmpm uses Spalding's
//! single formula for it (Spalding 1961, "A single formula for the law of the wall", J. Appl.
//! Mech. 28), valid from the viscous sublayer through the log layer:
//!
//! ```text
//! y+ = u+ + e^(-kappa B) (e^(kappa u+) - 1 - kappa u+ - (kappa u+)^2 / 2 - (kappa u+)^3 / 6),
//! u+ = U / u_tau,   y+ = y u_tau / nu,   tau_w = rho u_tau^2,   kappa = 0.4, B = 5.5.
//! ```
//!
//! Given U y / nu = u+ y+, the formula is solved for u+ ([`u_plus`]); close to the wall (y+ <
//! 5) it is the laminar shear mu U / y, far from it the log law. It has no parameter to set:
//! the fluid's viscosity and the grid give everything, and a wall of a glass or acrylic tank
//! is smooth.
//!
//! In the grid's terms: each face node of a slip wall that holds material (a released node of
//! a separating wall does not) is slowed along the wall by the shear on its share A of the
//! wall (h^(D-1), halved on each of the wall's edges), over its mass m, a force of the
//! predictor (step 2): v* loses tau_w A dt / m along the slide, and never more than it still
//! slides that way. U is the node's slide along the wall at the step's start (v^n relative to
//! the wall), the mass-weighted mean of its particles', and y the centroid of its shape
//! function's weights on the material side (h / 3 for linear shapes, 13 h / 32 for quadratic
//! B-splines), where that mean is taken. A node with little mass, the thin tip of a surge, is
//! slowed the most, as a thin layer is. At rest U = 0 and nothing changes: a column of water at
//! rest stays exact.

use crate::error::DeckError;
use crate::grid::Vector;
use crate::keys::Check;
use crate::material::Model;
use crate::shape::{ShapeFunction, PAD};
use serde::{Deserialize, Serialize};

/// von Karman's constant and the log law's intercept of Spalding (1961).
const KAPPA: f64 = 0.4;
const B: f64 = 5.5;

/// `grid.boundary.friction`: the shear of the slip walls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum WallFriction {
    /// None: the material slides freely along a slip wall.
    #[default]
    None,
    /// The smooth wall's shear from the law of the wall (this module).
    WallLaw,
}

impl WallFriction {
    /// Checks `grid.boundary.friction` against the materials: the law of the wall is that of
    /// a Newtonian fluid, and the shear needs the fluid's density and viscosity at each wall
    /// node, which the grid does not carry per node: every material must be the same
    /// Newtonian fluid with a viscosity. `materials`: (name, model, density, viscosity).
    pub(crate) fn check(
        self,
        c: &Check,
        materials: &[(&str, Model, f64, f64)],
        slip_faces: usize,
    ) -> Result<(), DeckError> {
        if self == Self::None {
            return Ok(());
        }
        const KEY: &str = "grid.boundary.friction";
        if slip_faces == 0 {
            return Err(c.err(
                KEY,
                "\"wall_law\" acts on \"slip\" faces, and this grid has none: make the walls \
                 that rub \"slip\", or leave the key out",
            ));
        }
        for &(name, model, _, mu) in materials {
            if model != Model::Newtonian || mu <= 0.0 {
                return Err(c.err(
                    KEY,
                    format!(
                        "\"wall_law\" is the law of the wall of a Newtonian fluid with a \
                         viscosity; material \"{name}\" is not one (model {model:?}, viscosity \
                         {mu} Pa s)"
                    ),
                ));
            }
        }
        let (first, _, rho, mu) = materials[0];
        if let Some(&(name, ..)) = materials.iter().find(|m| m.2 != rho || m.3 != mu) {
            return Err(c.err(
                KEY,
                format!(
                    "\"wall_law\" needs one fluid: materials \"{first}\" and \"{name}\" differ in \
                     density or viscosity (the grid does not know which one is at a wall node)"
                ),
            ));
        }
        Ok(())
    }
}

/// The wall shear of one fluid on a grid (module docs).
#[derive(Debug, Clone)]
pub struct WallLaw {
    /// Kinematic viscosity nu = mu / rho (m^2/s).
    nu: f64,
    /// Density (kg/m^3).
    rho: f64,
    /// Distance from the wall at which a face node samples the velocity (m).
    y: f64,
    /// A face node's share of the wall, h^(D-1) (m^(D-1)).
    area: f64,
}

impl WallLaw {
    /// The law for a fluid of density `rho` and dynamic viscosity `mu` on a grid of cell size
    /// `h` in `dim` dimensions, with shape functions `shape` (GIMP half-width `lp` in cells).
    pub fn new(rho: f64, mu: f64, h: f64, dim: usize, shape: ShapeFunction, lp: f64) -> Self {
        Self {
            nu: mu / rho,
            rho,
            y: sample_distance(shape, lp) * h,
            area: h.powi(dim as i32 - 1),
        }
    }

    /// Slows face node velocity `v` (v*, mass `m`) along a wall normal to `axis` moving at
    /// `wall`, over a step `dt`, by the wall shear of the node's slide `before` it (v^n) on
    /// its `share` of the wall (m^(D-1)): the shear is a force of the predictor, explicit in
    /// time like the others, so the projection sees it, and the gravity a side wall's v*
    /// carries before the pressure cancels it is not read as sliding. It takes at most the
    /// slide v* still has in that direction: it never reverses the node's motion along the
    /// wall, however light the node or opposed the other forces.
    #[inline]
    pub fn rub<const D: usize>(
        &self,
        v: &mut Vector<D>,
        before: &Vector<D>,
        (m, share): (f64, f64),
        axis: usize,
        wall: &Vector<D>,
        dt: f64,
    ) {
        let mut slide = *before - wall;
        slide[axis] = 0.0;
        let u = slide.norm();
        if u == 0.0 {
            return;
        }
        let along = slide / u;
        let mut now = *v - wall;
        now[axis] = 0.0;
        let slowed = (self.shear(u) * share * dt / m).min(now.dot(&along).max(0.0));
        for c in (0..D).filter(|&c| c != axis) {
            v[c] -= along[c] * slowed;
        }
    }

    /// A face node's share of the wall when it sits on no edge of it, h^(D-1) (m^(D-1)).
    pub fn area(&self) -> f64 {
        self.area
    }

    /// The wall shear tau_w (Pa) under material sliding at `u` (m/s).
    pub fn shear(&self, u: f64) -> f64 {
        let up = u_plus(u * self.y / self.nu);
        self.rho * (u / up) * (u / up)
    }
}

/// Spalding's y+ as a function of u+, and its derivative.
fn spalding(u: f64) -> (f64, f64) {
    let a = KAPPA * u;
    let c = (-KAPPA * B).exp();
    let e = a.exp();
    (
        u + c * (e - 1.0 - a - a * a / 2.0 - a * a * a / 6.0),
        1.0 + c * KAPPA * (e - 1.0 - a - a * a / 2.0),
    )
}

/// u+ = U / u_tau for a velocity U sampled at y, from `re` = U y / nu: the root of u+ y+(u+)
/// = re. The product grows with u+ and is convex, and y+ >= u+, so sqrt(re) bounds the root
/// from above; Newton's method from below that bound, kept in the bracket by bisection,
/// converges to round-off in a few iterations (the log law's estimate starts it).
pub fn u_plus(re: f64) -> f64 {
    if re <= 0.0 {
        return 0.0;
    }
    // deep in the sublayer u+ = y+ to round-off (the bracket's terms are of order u+^4 / 3e4,
    // and cancel in floating point below it)
    if re < 1e-6 {
        return re.sqrt();
    }
    let (mut lo, mut hi) = (0.0, re.sqrt());
    let log_law = ((re.max(1.0)).ln() / KAPPA + B).min(hi);
    let mut u = if re < 25.0 { hi } else { log_law };
    for _ in 0..100 {
        let (y, dy) = spalding(u);
        let f = u * y - re;
        if f > 0.0 {
            hi = u;
        } else {
            lo = u;
        }
        let next = u - f / (y + u * dy);
        let next = if next > lo && next < hi {
            next
        } else {
            0.5 * (lo + hi)
        };
        if (next - u).abs() <= 1e-12 * u {
            return next;
        }
        u = next;
    }
    u
}

/// The distance from a wall, in cells, of the centroid of the weights of the wall's own node
/// over the material side (the particles' mean velocity at that node is a mean over that
/// distribution): the midpoint rule over the shape function's support.
fn sample_distance(shape: ShapeFunction, lp: f64) -> f64 {
    const N: usize = 4096;
    let reach = shape.width() as f64;
    let (mut w, mut wx) = (0.0, 0.0);
    for k in 0..N {
        let xi = (k as f64 + 0.5) * reach / N as f64;
        let n = shape.weight_1d(xi, lp, PAD);
        w += n;
        wx += n * xi;
    }
    wx / w
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spalding_is_laminar_near_the_wall_and_the_log_law_beyond() {
        // viscous sublayer: u+ = y+, so u+^2 = U y / nu
        for re in [1e-6, 1e-2, 1.0, 4.0] {
            let u = u_plus(re);
            assert!((u * u / re - 1.0).abs() < 0.02, "re {re}: u+ {u}");
        }
        // log layer: u+ = ln(y+) / kappa + B, y+ = re / u+
        for re in [1e4, 1e5, 1e6] {
            let u = u_plus(re);
            let log = (re / u).ln() / KAPPA + B;
            assert!(
                (u / log - 1.0).abs() < 0.01,
                "re {re}: u+ {u}, log law {log}"
            );
        }
        // the root itself, to round-off
        for re in [0.3, 30.0, 300.0, 3e3, 3e7] {
            let u = u_plus(re);
            assert!((u * spalding(u).0 / re - 1.0).abs() < 1e-10, "re {re}");
        }
    }

    #[test]
    fn a_node_samples_its_weights_centroid() {
        assert!((sample_distance(ShapeFunction::Linear, 0.0) - 1.0 / 3.0).abs() < 1e-6);
        assert!((sample_distance(ShapeFunction::Bspline2, 0.0) - 13.0 / 32.0).abs() < 1e-6);
    }

    #[test]
    fn the_shear_slows_a_node_without_reversing_it() {
        let law = WallLaw::new(1000.0, 1e-3, 0.01, 2, ShapeFunction::Linear, 0.0);
        let wall = Vector::<2>::zeros();
        // a floor node's x velocity after the rub: v* x and y, v^n x, its mass
        let rubbed = |v_star: [f64; 2], before: f64, m: f64| {
            let mut v = Vector::<2>::new(v_star[0], v_star[1]);
            let before = Vector::<2>::new(before, 0.0);
            law.rub(&mut v, &before, (m, law.area()), 1, &wall, 1e-3);
            assert_eq!(
                v[1], v_star[1],
                "the normal component is the wall's business"
            );
            v[0]
        };
        // a full floor node (half a cell of water, 0.05 kg per metre) sliding at 1 m/s
        let tau = law.shear(1.0);
        let v = rubbed([1.0, -0.1], 1.0, 0.05);
        assert!((v - (1.0 - tau * 0.01 * 1e-3 / 0.05)).abs() < 1e-14);
        // a nearly empty node stops along the wall, and no further
        assert_eq!(rubbed([1.0, 0.0], 1.0, 1e-9), 0.0);
        // a light node whose other forces already slowed v* to 0.2 m/s stops there, not at
        // -0.8 m/s; one they pushed back past the wall's speed is left alone
        assert_eq!(rubbed([0.2, 0.0], 1.0, 1e-9), 0.0);
        assert_eq!(rubbed([-0.3, 0.0], 1.0, 1e-9), -0.3);
        // at rest (v^n) a node is not rubbed, whatever its v* (gravity along a side wall)
        let mut v = Vector::<2>::new(0.0, -0.05);
        law.rub(
            &mut v,
            &Vector::<2>::zeros(),
            (0.05, law.area()),
            0,
            &wall,
            1e-3,
        );
        assert_eq!(v[1], -0.05);
    }

    #[test]
    fn u_plus_is_continuous_where_the_sublayer_shortcut_starts() {
        let (below, above) = (u_plus(0.999_999e-6), u_plus(1.000_001e-6));
        assert!((below / above - 1.0).abs() < 1e-6, "{below} {above}");
    }
}
