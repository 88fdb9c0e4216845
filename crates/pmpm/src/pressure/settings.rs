//! The projection's settings, as the deck's `[pressure]` table spells them.

use super::free_surface::FreeSurface;
use super::{PoissonRhs, PressureUnknowns, Quadrature, RigidFaces};
use crate::shape::ShapeFunction;
use serde::{Deserialize, Serialize};

/// Linear solver of the pressure Poisson equation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Solver {
    /// Preconditioned conjugate gradient.
    #[default]
    Pcg,
    /// Sparse Cholesky.
    Direct,
}

/// Grid cells from which the multigrid is the default preconditioner (docs/deck.md has the
/// timings this threshold comes from).
pub const MULTIGRID_CELLS: usize = 10_000;

/// Preconditioner of the conjugate gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preconditioner {
    /// Diagonal scaling.
    Jacobi,
    /// Incomplete Cholesky, no fill.
    Ic0,
    /// Geometric multigrid.
    Multigrid,
}

/// How the projection keeps each particle's volume from drifting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DensityCorrection {
    /// After each step, a second Poisson solve on the particles' volume error moves the
    /// particles (and deforms their F) so that each one's volume J V0 returns towards V0
    /// (`crates/pmpm/src/pressure/density.rs`). The default for fluids with a free surface.
    #[default]
    Positions,
    /// The same solve and move, with the density measured from where the particles are, not
    /// from J: each node's error is the rest volume its particles spread onto it,
    /// sum_p V0_p N_ip, less the volume its shape function covers in the open domain
    /// (Kugelstadt et al., 2021). It removes the particles' bunching as well as compression;
    /// J follows the move.
    Particles,
    /// None: the paper's scheme; the default without a free surface and for solids.
    None,
}

/// The projection's settings: the deck's `[pressure]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct PressureSettings {
    #[serde(default)]
    pub solver: Solver,
    /// The deck's choice; [`PressureSettings::preconditioner`] gives the one used.
    #[serde(default)]
    pub preconditioner: Option<Preconditioner>,
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    #[serde(default = "default_max_iterations")]
    pub max_iterations: usize,
    /// Most pressure solves per step with nodal unknowns: the first projects v*, each further
    /// one the divergence the corrector and the wall conditions left (1: the paper's single
    /// solve).
    #[serde(default = "default_passes")]
    pub passes: usize,
    /// How p = 0 is imposed; `validate` fills it in (the level set).
    #[serde(default)]
    pub free_surface: Option<FreeSurface>,
    #[serde(default = "default_vf_tolerance")]
    pub volume_fraction_tolerance: f64,
    #[serde(default = "default_beta")]
    pub beta: f64,
    #[serde(default)]
    pub rhs: PoissonRhs,
    /// Quadrature of L and the right-hand side (default: the cells' Gauss points).
    #[serde(default)]
    pub quadrature: Quadrature,
    /// Bubble closing in the free-surface detection: a face-connected set of cells at or below
    /// the volume-fraction tolerance with at most this many cells, not reaching an open face,
    /// counts as filled (a gap the flow spread between particles, not air). 0 turns it off.
    #[serde(default = "default_bubble_cells")]
    pub bubble_cells: usize,
    /// Volume correction (pmpm, experimental): the projection aims at div v = alpha (1 - J) / dt
    /// instead of 0, with J the particles' volume ratio averaged over each cell, giving back the
    /// fraction alpha of the volume the discrete projection let drift, per step. 0 (the
    /// default) turns it off.
    #[serde(default)]
    pub volume_correction: f64,
    /// How each particle's volume is kept from drifting; the deck's check fills it in:
    /// "particles" for a fluid (with a free surface only with linear shapes and no free rigid
    /// body, "positions" otherwise), "none" for solids and the explicit scheme.
    #[serde(default)]
    pub density_correction: Option<DensityCorrection>,
    /// Where the pressure unknowns sit: "nodes" (docs/method.md, the default) or "cells".
    #[serde(default)]
    pub unknowns: PressureUnknowns,
    /// How the nodal projection sees the rigid bodies' faces; left out, cut cells where they
    /// apply ([`PressureSettings::cuts_cells`]), the nodes elsewhere.
    #[serde(default)]
    pub rigid_faces: Option<RigidFaces>,
}

fn default_tolerance() -> f64 {
    1e-8
}
fn default_max_iterations() -> usize {
    2000
}
fn default_passes() -> usize {
    3
}
/// Gaps of up to 8 cells inside the fluid are closed (at h = a / 20 in the dam break 1 to 2
/// cell gaps open; 8, 16 and 64 behave the same there).
fn default_bubble_cells() -> usize {
    8
}
/// Chorin's split, as in the paper.
fn default_beta() -> f64 {
    0.0
}
fn default_vf_tolerance() -> f64 {
    0.3
}

impl PressureSettings {
    /// The conjugate gradient's preconditioner on a grid of `cells` cells: the deck's, or by
    /// default the multigrid for nodal unknowns on grids of at least [`MULTIGRID_CELLS`] cells
    /// (its iterations stay about flat as the grid grows, Jacobi's grow with its width) and
    /// Jacobi otherwise (on small grids a Jacobi iteration is cheap enough that its extra
    /// iterations cost less than the V-cycles; the multigrid is not built for cell unknowns).
    pub fn preconditioner(&self, cells: usize) -> Preconditioner {
        self.preconditioner.unwrap_or(
            if self.unknowns == PressureUnknowns::Nodes && cells >= MULTIGRID_CELLS {
                Preconditioner::Multigrid
            } else {
                Preconditioner::Jacobi
            },
        )
    }

    /// Whether cut-cell rigid faces can apply with these settings: linear or GIMP shape
    /// functions (with the B-splines a plate pushed into water let it through its face), the
    /// level-set free surface and nodal unknowns.
    pub fn cut_cells_apply(&self, shape: ShapeFunction) -> bool {
        matches!(shape, ShapeFunction::Linear | ShapeFunction::Gimp)
            && self.free_surface.unwrap_or_default() == FreeSurface::LevelSet
            && self.unknowns == PressureUnknowns::Nodes
    }

    /// Whether the projection sees the rigid bodies' faces where they lie: asked for, or left
    /// out where cut cells apply.
    pub fn cuts_cells(&self, shape: ShapeFunction) -> bool {
        match self.rigid_faces {
            Some(RigidFaces::Cut) => true,
            Some(RigidFaces::Nodes) => false,
            None => self.cut_cells_apply(shape),
        }
    }
}

impl Default for PressureSettings {
    fn default() -> Self {
        Self {
            solver: Solver::default(),
            preconditioner: None,
            tolerance: default_tolerance(),
            max_iterations: default_max_iterations(),
            passes: default_passes(),
            free_surface: None,
            volume_fraction_tolerance: default_vf_tolerance(),
            beta: default_beta(),
            rhs: PoissonRhs::default(),
            quadrature: Quadrature::default(),
            bubble_cells: default_bubble_cells(),
            volume_correction: 0.0,
            density_correction: None,
            unknowns: PressureUnknowns::default(),
            rigid_faces: None,
        }
    }
}
