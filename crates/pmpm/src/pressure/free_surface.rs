//! Free-surface detection (docs/method.md, step 3): which nodes carry p = 0.
//!
//! A cell counts as filled when the volume of the particles in it exceeds
//! `volume_fraction_tolerance` of the cell's volume. A node with mass is an unknown of the
//! Poisson equation when every cell around it is filled, and a free-surface node (p = 0)
//! otherwise. Cells beyond a closed wall count as filled (the wall is not a free surface),
//! cells beyond an open face as empty (the pressure there is the ambient one).
use crate::grid::{CellBins, GridGeometry};
use crate::pages;
use crate::shape::PAD;
use rayon::prelude::*;

use serde::{Deserialize, Serialize};

/// How free-surface (p = 0) nodes are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FreeSurface {
    /// A level set of the volume fraction, phi = h (1 - 2 f) with f the node's mean cell
    /// fraction: every node inside the fluid (phi < 0) is an unknown, and p = 0 is imposed
    /// where phi crosses zero between nodes, by a ghost-fluid value (Gibou et al. 2002).
    #[default]
    LevelSet,
    /// The paper's rule: p = 0 on every node next to a cell whose particle volume fraction is
    /// at or below `volume_fraction_tolerance`.
    VolumeFraction,
    /// No free surface: the fluid fills its container, every cell counts as full (a cell the
    /// particles left empty takes the mean density), p = 0 only on open faces. For closed or
    /// periodic flows (lid-driven cavity, channels, vortices), where a gap the particles open
    /// is not air.
    None,
}

pub use crate::grid::NodeKind;

/// The free surface of one solve: the cells' volume fractions, the level set and each node's
/// role, with the settings that find them. The stage "detect the free surface" of the
/// projection, and of the density correction.
#[derive(Debug)]
pub struct Surface {
    method: FreeSurface,
    tolerance: f64,
    bubble_cells: usize,
    /// Whether an under-filled cell between two fuller ones is filled ([`close_cracks`]):
    /// with the density measured from the particles' positions.
    cracks: bool,
    /// Whether each face (x_min, x_max, y_min, ...) is open.
    pub open: Vec<bool>,
    /// Whether a cell past each face counts as full to [`close_cracks`]: a closed face that
    /// is no ceiling ([`Surface::set_ceilings`]).
    behind: Vec<bool>,
    /// Particle volume fraction of each cell (numbered like its lower-corner node), with
    /// enclosed gaps closed.
    pub fraction: Vec<f64>,
    raw: Vec<f64>,
    /// The paper's rule: the fractions with the rigid bodies' cover added; the level set: its
    /// work buffer.
    covered: Vec<f64>,
    /// Share of each cell the rigid bodies cover (empty without rigid bodies).
    solid: Vec<f64>,
    /// Level set of the fluid at the nodes, negative inside (with `FreeSurface::LevelSet`).
    pub phi: Vec<f64>,
    /// Role of each node.
    pub kinds: Vec<NodeKind>,
    flood: FloodFill,
    /// Over ranks, the slabs' comm and this rank's own cell layers along the cut axis
    /// ([`Surface::spread_over`]); `None` on one process.
    owners: Option<Owners>,
}

/// Over ranks: the comm whose sums onto the nodes also copy the window's layers
/// ([`crate::slabs::Sliced`]), the cut axis, and this rank's own layers along it.
#[derive(Clone)]
pub struct Owners {
    /// The slabs' comm.
    pub comm: std::sync::Arc<dyn crate::comm::Comm>,
    /// The cut axis.
    pub axis: usize,
    /// This rank's own cell layers along `axis`.
    pub layers: std::ops::Range<usize>,
    /// The layers past them the stages read ([`crate::slabs::Decomposition::reach`]).
    pub reach: usize,
}

impl std::fmt::Debug for Owners {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Owners(axis {}, layers {:?})", self.axis, self.layers)
    }
}

impl Surface {
    /// The settings of `[pressure]`, and which faces are open.
    pub fn new<const D: usize>(
        pd: &super::PressureSettings,
        boundary: &crate::boundary::Boundary<D>,
    ) -> Self {
        let mut s = Self::with_settings(
            pd.free_surface.unwrap_or_default(),
            pd.volume_fraction_tolerance,
            pd.bubble_cells,
            (0..2 * D).map(|f| boundary.is_open(f)).collect(),
        );
        s.cracks = pd.density_correction == Some(super::DensityCorrection::Particles);
        s
    }

    /// The faces the body force `gravity` pulls the fluid away from (its outward normal n
    /// with g . n < 0: a lid, and any face facing down) are ceilings: a gap one cell deep
    /// under one is water falling away, not a crack between bunched particles, so
    /// [`close_cracks`] does not fill it (it did, and held a block of water to a lid it
    /// should have left as free water; against a floor or a side wall the water's own
    /// pressure closes such a gap).
    pub fn set_ceilings(&mut self, gravity: &[f64]) {
        for (f, behind) in self.behind.iter_mut().enumerate() {
            let (d, side) = (f / 2, f % 2);
            let g_out = if side == 0 { -gravity[d] } else { gravity[d] };
            *behind = !self.open[f] && g_out >= 0.0;
        }
    }

    /// The method, the volume-fraction tolerance, the bubble bound and which faces are open.
    fn with_settings(
        method: FreeSurface,
        tolerance: f64,
        bubble_cells: usize,
        open: Vec<bool>,
    ) -> Self {
        Self {
            method,
            tolerance,
            bubble_cells,
            cracks: false,
            behind: open.iter().map(|o| !o).collect(),
            open,
            fraction: Vec::new(),
            raw: Vec::new(),
            covered: Vec::new(),
            solid: Vec::new(),
            phi: Vec::new(),
            kinds: Vec::new(),
            flood: FloodFill::default(),
            owners: None,
        }
    }

    /// Makes this the free surface of a rank whose own cells are `owners`' (the window's
    /// cells then take their fractions, and the closing of their gaps, from their owners);
    /// `None`: one process's.
    pub fn spread_over(&mut self, owners: Option<Owners>) {
        self.owners = owners;
    }

    /// The level set, where the method has one.
    pub fn level_set(&self) -> Option<&[f64]> {
        (self.method == FreeSurface::LevelSet).then_some(&self.phi[..])
    }

    /// The share of each cell rigid bodies cover, where there are rigid bodies.
    pub fn solid(&self) -> Option<&[f64]> {
        (!self.solid.is_empty()).then_some(&self.solid[..])
    }

    /// Finds each node's role from the particles (binned in `bins`, volumes `volume`) and the
    /// nodes' mass: volume fractions, enclosed gaps closed, rigid bodies read as walls, then
    /// the level set and the ghost-fluid roles, or the paper's rule.
    pub fn detect<const D: usize>(
        &mut self,
        geo: &GridGeometry<D>,
        bins: &CellBins,
        volume: &[f64],
        mass: &[f64],
        mass_epsilon: f64,
        rigid: &crate::rigid::RigidBodies<D>,
    ) {
        volume_fractions(geo, bins, volume, &mut self.fraction);
        // over ranks, each cell's fraction as its owner found it from its own particles: the
        // ghosts reach only a layer or two past the slab ([`crate::slabs::GHOST_LAYERS`]), the
        // window's cells further than that hold only what the owners give them
        if let Some(owners) = &self.owners {
            take_owners(geo, owners, &mut self.fraction, true);
        }
        if self.method == FreeSurface::None {
            // the fluid fills its container: every cell full (the cells past the walls are
            // left to the classification, which reads the faces)
            self.fraction.par_iter_mut().for_each(|f| *f = f.max(1.0));
        } else if self.bubble_cells > 0 {
            std::mem::swap(&mut self.fraction, &mut self.raw);
            // a cell is under-filled below the level at which the method puts the surface: the
            // level set puts it where the nodes' mean fraction is 1/2 (two half-filled cells
            // on a floor, their particles drawn apart, read as air and dropped the whole
            // column's pressure by a third for a step)
            let low = match self.method {
                FreeSurface::LevelSet => self.tolerance.max(0.5),
                _ => self.tolerance,
            };
            close_bubbles(
                geo,
                &self.raw,
                low,
                &self.open,
                self.bubble_cells,
                &mut self.flood,
                &mut self.fraction,
            );
            if self.cracks {
                let low = match self.method {
                    FreeSurface::LevelSet => self.tolerance.max(0.5),
                    _ => self.tolerance,
                };
                let cracks = &mut self.flood.component;
                close_cracks(geo, low, &self.behind, &mut self.fraction, cracks);
            }
            // over ranks, the window's cells as their owners closed them (after the cracks,
            // which read a cell's face neighbours: those next to the slab are right here)
            if let Some(owners) = &self.owners {
                take_owners(geo, owners, &mut self.fraction, false);
            }
        }
        // the share of each cell the rigid bodies cover
        self.solid.clear();
        if !rigid.is_empty() {
            self.solid.resize(geo.node_count(), 0.0);
            rigid.cover(geo, &mut self.solid);
            if self.method == FreeSurface::LevelSet {
                rigid.fill_cut_cells(geo, &self.solid, &mut self.fraction);
            }
        }
        if self.method == FreeSurface::LevelSet {
            // a rigid body is neither water nor air: the level set weighs only the part of
            // each cell it leaves open
            let solid = (!self.solid.is_empty()).then_some(&self.solid[..]);
            // over ranks the rank's own layers and as far as the stages read the level set
            // past them, with a layer to spare
            let view = self.owners.as_ref().map(|o| {
                let w = o.reach + 1;
                (o.axis, o.layers.start.saturating_sub(w)..o.layers.end + w)
            });
            level_set(
                geo,
                (&self.fraction, solid),
                &self.open,
                view.as_ref(),
                &mut self.phi,
                &mut self.covered,
            );
            classify_level_set(
                geo,
                mass,
                mass_epsilon,
                &self.phi,
                solid,
                &self.open,
                &mut self.kinds,
            );
        } else {
            // the paper's rule reads a rigid body as a wall: the cells it covers count as full
            let fraction = if self.solid.is_empty() {
                &self.fraction
            } else {
                self.covered.clone_from(&self.fraction);
                for (c, s) in self.covered.iter_mut().zip(&self.solid) {
                    *c += s;
                }
                &self.covered
            };
            classify(
                geo,
                mass,
                mass_epsilon,
                fraction,
                self.tolerance,
                &self.open,
                &mut self.kinds,
            );
        }
    }
}

/// Over ranks, every cell's fraction as the rank that owns it found it (the cells outside
/// the slab zeroed, then the sums onto the nodes, which copy the window's layers): before the
/// gaps are closed, the fractions of the cells' own particles, so that the window's cells
/// need no ghosts; after, the fractions as their owners closed them. A rank's own cells are
/// closed right: a gap of at most `bubble_cells` cells that holds one of them lies within
/// `bubble_cells` layers of its slab, inside the window ([`crate::slabs::window_of`]); a
/// larger one reaches past the window into the empty cells beyond, and stays open as it
/// should. A window cell's gap may reach past the window, where this rank cannot see it, so
/// its owner's closing is taken: the window need not hold a whole gap past each of its own
/// cells, only as far as the later stages read. So the raw fractions (`wide`) come onto the
/// whole window, `bubble_cells` layers deep, and the closed ones onto the stages' reach
/// ([`crate::slabs::Decomposition::sums_window`]).
fn take_owners<const D: usize>(
    geo: &GridGeometry<D>,
    owners: &Owners,
    fraction: &mut [f64],
    wide: bool,
) {
    super::ranks::keep_layers(geo, owners.axis, &owners.layers, fraction);
    if wide {
        owners.comm.add_nodes_wide(&mut [fraction]);
    } else {
        owners.comm.add_nodes(&mut [fraction]);
    }
}

/// Particle volume fraction of every cell: sum of the particles' volumes / h^D.
pub fn volume_fractions<const D: usize>(
    geo: &GridGeometry<D>,
    bins: &CellBins,
    volume: &[f64],
    out: &mut Vec<f64>,
) {
    let inv = 1.0 / geo.h.powi(D as i32);
    pages::fit(out, geo.node_count());
    out.par_iter_mut().enumerate().for_each(|(c, f)| {
        // (a fold from +0: `sum` starts from -0, which an empty cell would keep, and its
        // store would commit the air's pages)
        let fraction = bins
            .particles(c)
            .iter()
            .fold(0.0, |sum, &p| sum + volume[p as usize])
            * inv;
        pages::store(f, fraction);
    });
}

/// One of the 2^D cells around a node: in the grid, or beyond a closed or an open face.
enum Corner {
    /// A cell of the grid (flat index; periodic directions wrapped).
    Cell(usize),
    /// Beyond a wall: read as full.
    Closed,
    /// Beyond an open face: read as empty.
    Open,
}

/// The cell `node - 1 + e` around `node`, e the bits of `corner` (bit d along axis d).
#[inline]
fn corner_cell<const D: usize>(
    geo: &GridGeometry<D>,
    node: &[usize; D],
    corner: usize,
    open: &[bool],
) -> Corner {
    let mut inside = true;
    let mut closed = true;
    let mut cell = [0usize; D];
    for d in 0..D {
        let mut c = (node[d] + ((corner >> d) & 1)) as isize - 1;
        if geo.periodic[d] {
            c = PAD as isize + (c - PAD as isize).rem_euclid(geo.cells[d] as isize);
        }
        if c < PAD as isize {
            inside = false;
            closed &= !open[2 * d];
        } else if c >= (PAD + geo.cells[d]) as isize {
            inside = false;
            closed &= !open[2 * d + 1];
        }
        cell[d] = c.max(0) as usize;
    }
    if inside {
        Corner::Cell(geo.flat(&cell))
    } else if closed {
        Corner::Closed
    } else {
        Corner::Open
    }
}

/// Classifies every node from its mass and the volume fractions of the 2^D cells around it.
/// `open[f]` tells whether face f (x_min, x_max, y_min, ...) is open.
pub fn classify<const D: usize>(
    geo: &GridGeometry<D>,
    mass: &[f64],
    mass_epsilon: f64,
    fraction: &[f64],
    tolerance: f64,
    open: &[bool],
    kinds: &mut Vec<NodeKind>,
) {
    pages::fit(kinds, geo.node_count());
    kinds.par_iter_mut().enumerate().for_each(|(i, kind)| {
        if mass[i] <= mass_epsilon {
            pages::store(kind, NodeKind::Empty);
            return;
        }
        let node = geo.multi(i);
        let mut filled = true;
        for corner in 0..(1usize << D) {
            let full = match corner_cell(geo, &node, corner, open) {
                Corner::Cell(c) => fraction[c] > tolerance,
                Corner::Closed => true,
                Corner::Open => false,
            };
            if !full {
                filled = false;
                break;
            }
        }
        let role = if filled {
            NodeKind::Interior
        } else {
            NodeKind::FreeSurface
        };
        pages::store(kind, role);
    });
}

/// Smallest share of a node-to-node segment the ghost-fluid condition gives the fluid side:
/// nearer the surface than this, a node's equation is held as if the surface were this far
/// (Gibou et al. 2002 bound the same ratio; without a bound the diagonal grows without limit).
pub const THETA_MIN: f64 = 0.01;

/// A node of the level set closer to the surface than this share of a cell counts as on it.
const ON_SURFACE: f64 = 1e-9;

/// Level set of the fluid at every node, phi_i = h (1 - 2 f_i), negative inside, from f_i the
/// share of fluid in the 2^D cells around the node (a cell beyond a closed wall the mirror
/// image of the cell inside it, beyond an open face empty), counting only the part of each cell
/// no rigid body covers.
///
/// For a plane surface parallel to the grid, f_i falls linearly from 1 to 0 as the node goes
/// from a cell inside the surface to a cell outside it, so phi is the signed distance to the
/// surface within a cell of it; elsewhere it is a smoothed volume fraction whose zero lies
/// where the fluid fills half of a node's cells.
///
/// A node that a rigid body covers more than half of (one inside a face) takes the least phi of
/// its neighbours that it covers less than half of: its own open part can be a sliver, whose
/// particles (a few, or none) would read the water against the face as air or not, step by
/// step. `scratch` is a work buffer.
///
/// Over ranks only the nodes on the node layers `view` (an axis and its layers: the rank's
/// own and its window's) are set, and the others are zero, on pages left uncommitted: a rank
/// reads the level set no further, and the air's h would commit the whole box on every rank.
pub fn level_set<const D: usize>(
    geo: &GridGeometry<D>,
    (fraction, solid): (&[f64], Option<&[f64]>),
    open: &[bool],
    view: Option<&(usize, std::ops::Range<usize>)>,
    phi: &mut Vec<f64>,
    scratch: &mut Vec<f64>,
) {
    let corners = 1usize << D;
    let seen = |node: &[usize; D]| view.is_none_or(|(axis, layers)| layers.contains(&node[*axis]));
    pages::fit(phi, geo.node_count());
    // a line of nodes along axis 0 at a time: a line whose cells hold no fluid (the air, most
    // of a tank) is h throughout, found from its cells' lines without a node's corners
    let line = geo.nodes[0];
    phi.par_chunks_mut(line).enumerate().for_each(|(l, row)| {
        let mut node = geo.multi(l * line);
        let dry = solid.is_none() && dry_line(geo, fraction, &node, open);
        for (k, phi) in row.iter_mut().enumerate() {
            node[0] = k;
            let value = match (seen(&node), dry) {
                (false, _) => 0.0,
                (true, true) => geo.h,
                (true, false) => level_at(geo, (fraction, solid), open, &node),
            };
            pages::store(phi, value);
        }
    });
    let Some(solid) = solid else {
        return;
    };
    let half = 0.5 * corners as f64;
    let room = |node: &[usize; D]| -> f64 {
        (0..corners)
            .map(|corner| {
                mirrored_cell(geo, node, corner, open)
                    .map_or(1.0, |c| 1.0 - solid[c].clamp(0.0, 1.0))
            })
            .sum()
    };
    pages::copy(scratch, phi);
    let own = &scratch[..];
    phi.par_iter_mut().enumerate().for_each(|(i, phi)| {
        let node = geo.multi(i);
        if !seen(&node) || room(&node) >= half {
            return;
        }
        // the nodes across a face first: the level set goes on into the body along the
        // face's normal, so a water line meeting a vertical face between node rows stays
        // where it is; a diagonal neighbour, a row deeper in the water, put the node on the
        // water line inside the body under the surface (an unknown without its p = 0), and
        // set still water around a box held across the surface moving
        let least_of = |along_axes: bool| {
            let mut least = f64::INFINITY;
            let take = |j: usize| {
                if room(&geo.multi(j)) >= half {
                    least = least.min(own[j]);
                }
            };
            if along_axes {
                for_each_axis_neighbour(geo, &node, take);
            } else {
                for_each_neighbour(geo, &node, take);
            }
            least
        };
        let mut least = least_of(true);
        if !least.is_finite() {
            // (a node past a body's edge, with only diagonal neighbours in the open)
            least = least_of(false);
        }
        if least.is_finite() {
            pages::store(phi, least);
        }
    });
}

/// The level set at `node` from the fluid's share of the open part of its `2^D` cells
/// ([`level_set`]).
#[inline]
fn level_at<const D: usize>(
    geo: &GridGeometry<D>,
    (fraction, solid): (&[f64], Option<&[f64]>),
    open: &[bool],
    node: &[usize; D],
) -> f64 {
    let (mut f, mut room) = (0.0, 0.0);
    for corner in 0..1usize << D {
        match mirrored_cell(geo, node, corner, open) {
            Some(c) => {
                // the part of the cell a rigid body leaves open, and the fluid in it
                let open_part = 1.0 - solid.map_or(0.0, |s| s[c].clamp(0.0, 1.0));
                f += fraction[c].clamp(0.0, open_part);
                room += open_part;
            }
            None => room += 1.0,
        }
    }
    // inside a body the node is no part of the fluid's domain (classify_level_set
    // buries it); read it as inside so that it puts no surface at the body's face
    let f = if room > 1e-9 { f / room } else { 1.0 };
    let p = 1.0 - 2.0 * f;
    // a node on the surface to round-off is on it, so that a column at rest whose top
    // lies on a node row holds p = 0 there exactly
    geo.h * if p.abs() < ON_SURFACE { 0.0 } else { p }
}

/// Whether no cell that a node of the line along axis 0 through `node` reads
/// ([`mirrored_cell`]) holds fluid: those cells lie on at most `2^(D-1)` lines of cells along
/// axis 0 (the reflections and wraps along axis 0 stay on a line), each read whole. Then
/// [`level_at`] is h at every node of the line (without rigid bodies, whose open part it
/// weighs).
fn dry_line<const D: usize>(
    geo: &GridGeometry<D>,
    fraction: &[f64],
    node: &[usize; D],
    open: &[bool],
) -> bool {
    let line = geo.nodes[0];
    (0..1usize << (D - 1)).all(|bits| {
        let mut start = 0;
        for d in 1..D {
            let c = node[d] as isize + ((bits >> (d - 1)) & 1) as isize - 1 - PAD as isize;
            match mirrored_index(geo, d, c, open) {
                Some(c) => start += (c as usize + PAD) * geo.strides[d],
                // past an open face: no cell, no fluid
                None => return true,
            }
        }
        fraction[start..start + line].iter().all(|&f| f <= 0.0)
    })
}

/// Cell `c` along axis `d` (counted from the grid's first cell, not the padding), wrapped
/// across a periodic axis and reflected back across a closed wall as often as it takes; None
/// beyond an open face ([`mirrored_cell`]).
#[inline]
fn mirrored_index<const D: usize>(
    geo: &GridGeometry<D>,
    d: usize,
    mut c: isize,
    open: &[bool],
) -> Option<isize> {
    let n = geo.cells[d] as isize;
    if geo.periodic[d] {
        c = c.rem_euclid(n);
    }
    while c < 0 || c >= n {
        if c < 0 {
            if open[2 * d] {
                return None;
            }
            c = -1 - c;
        } else {
            if open[2 * d + 1] {
                return None;
            }
            c = 2 * n - 1 - c;
        }
    }
    Some(c)
}

/// The cell `node - 1 + e` around `node` (e the bits of `corner`), reflected back into the
/// grid across a closed wall (a wall is a plane of symmetry of the fluid's shape: a surface
/// meeting it at a node reads as meeting it there), wrapped across a periodic one; None beyond
/// an open face (empty).
#[inline]
fn mirrored_cell<const D: usize>(
    geo: &GridGeometry<D>,
    node: &[usize; D],
    corner: usize,
    open: &[bool],
) -> Option<usize> {
    let mut cell = [0usize; D];
    for d in 0..D {
        let lo = PAD as isize;
        let c = (node[d] + ((corner >> d) & 1)) as isize - 1 - lo;
        cell[d] = (mirrored_index(geo, d, c, open)? + lo) as usize;
    }
    Some(geo.flat(&cell))
}

/// Classifies the nodes from the level set: a node with mass inside the fluid (phi < 0) is an
/// unknown; one with mass on or outside the surface is a free-surface node, whose pressure is
/// the ghost value of [`ghost_values`]. `solid[c]` is the share of cell c a rigid body covers:
/// a node all of whose cells are covered is not in the fluid's domain.
pub fn classify_level_set<const D: usize>(
    geo: &GridGeometry<D>,
    mass: &[f64],
    mass_epsilon: f64,
    phi: &[f64],
    solid: Option<&[f64]>,
    open: &[bool],
    kinds: &mut Vec<NodeKind>,
) {
    pages::fit(kinds, geo.node_count());
    kinds.par_iter_mut().enumerate().for_each(|(i, kind)| {
        let role = if mass[i] <= mass_epsilon {
            NodeKind::Empty
        } else if phi[i] < 0.0 {
            NodeKind::Interior
        } else {
            NodeKind::FreeSurface
        };
        pages::store(kind, role);
        if *kind == NodeKind::Interior {
            if let Some(solid) = solid {
                let node = geo.multi(i);
                // a cell beyond a wall reads as its mirror image inside (a ghost node behind
                // the floor is no part of a body unless the cells it mirrors are)
                let buried = (0..(1usize << D)).all(|corner| {
                    mirrored_cell(geo, &node, corner, open).is_some_and(|c| solid[c] >= 1.0 - 1e-9)
                });
                if buried {
                    *kind = NodeKind::Solid;
                }
            }
        }
    });
}

/// Extends a nodal field into the rigid bodies: each [`NodeKind::Solid`] node next to the
/// fluid's nodes takes the mean of their values, then each next to those the mean of theirs
/// (two layers: the widest shape function, the cubic B-spline, reaches two nodes past a face).
/// The assembly read a solid node's pressure as the value of the node it couples to; this
/// gives the particles near a face, their pressure and its gradient, the same Neumann reading,
/// not a drop to 0 inside the body. `scratch` is a work buffer.
pub fn extend_into_solids<const D: usize>(
    geo: &GridGeometry<D>,
    kinds: &[NodeKind],
    field: &mut [f64],
    scratch: &mut Vec<f64>,
) {
    // NaN marks a value not known yet
    scratch.clear();
    scratch.extend(field.iter().zip(kinds).map(|(&f, k)| match k {
        NodeKind::Interior | NodeKind::FreeSurface => f,
        NodeKind::Empty | NodeKind::Solid => f64::NAN,
    }));
    for _ in 0..2 {
        let known = &scratch[..];
        field.par_iter_mut().enumerate().for_each(|(j, fj)| {
            if kinds[j] != NodeKind::Solid || !known[j].is_nan() {
                return;
            }
            let (mut sum, mut n) = (0.0, 0usize);
            for_each_neighbour(geo, &geo.multi(j), |i| {
                let v = known[geo.canonical(i)];
                if !v.is_nan() {
                    sum += v;
                    n += 1;
                }
            });
            *fj = if n > 0 { sum / n as f64 } else { f64::NAN };
        });
        for ((s, &f), k) in scratch.iter_mut().zip(field.iter()).zip(kinds) {
            if *k == NodeKind::Solid && s.is_nan() {
                *s = f;
            }
        }
    }
    // a solid node neither layer reached holds 0
    for f in field.iter_mut() {
        if f.is_nan() {
            *f = 0.0;
        }
    }
}

/// Velocities of the free-surface nodes that no pressure reaches, extended from the walls.
///
/// A free-surface node with an unknown among its 3^D neighbours is corrected by the ghost
/// pressure. One without (a layer of fluid thinner than half a cell, such as a dam break's
/// front on the floor) would keep its predicted velocity, gravity and all, while the wall node
/// below it holds the normal velocity: the layer's particles, between the two, would be packed
/// against the wall step after step. Each velocity component of such a node takes the mean of
/// that component over its neighbours that hold it (bit d of `held[i]` set: the wall's normal, a
/// rigid body's components), where there are any; the fluid's velocity extended into its
/// surface layer, as a projection on a staggered grid extends it into the air (Bridson, Fluid
/// Simulation for Computer Graphics, 2nd ed., 2015, section 4.4). A wall pushes, it does not
/// pull: a component that moves the node away from the holding nodes' side (a film under a lid,
/// falling) keeps its own value, as a separating contact would.
pub fn extend_velocity<const D: usize>(
    geo: &GridGeometry<D>,
    kinds: &[NodeKind],
    held: &[u8],
    v: &mut [crate::grid::Vector<D>],
    scratch: &mut Vec<crate::grid::Vector<D>>,
) {
    pages::copy(scratch, v);
    let old = &scratch[..];
    v.par_iter_mut().enumerate().for_each(|(j, vj)| {
        if kinds[j] != NodeKind::FreeSurface {
            return;
        }
        let mut sum = crate::grid::Vector::<D>::zeros();
        let mut count = [0usize; D];
        // per component, on which side the nodes that hold it lie (their offsets summed)
        let mut side = [0isize; D];
        let mut reached = false;
        let nj = geo.multi(j);
        for_each_neighbour(geo, &nj, |i| {
            reached |= kinds[geo.canonical(i)] == NodeKind::Interior;
            let ni = geo.multi(i);
            for d in 0..D {
                if held[i] & (1 << d) != 0
                    && matches!(kinds[i], NodeKind::Interior | NodeKind::FreeSurface)
                {
                    sum[d] += old[i][d];
                    count[d] += 1;
                    side[d] += ni[d] as isize - nj[d] as isize;
                }
            }
        });
        if reached {
            return;
        }
        for d in 0..D {
            if count[d] > 0 && held[j] & (1 << d) == 0 {
                let extended = sum[d] / count[d] as f64;
                // a layer moving away from the wall that holds it leaves it (water falls off a
                // lid): only the motion into the wall is taken away
                if (vj[d] - extended) * side[d] as f64 >= 0.0 {
                    vj[d] = extended;
                }
            }
        }
    });
}

/// Calls `f` with the flat index of each node next to `node` along an axis (2 D of them,
/// fewer at the padded grid's edges).
#[inline]
fn for_each_axis_neighbour<const D: usize>(
    geo: &GridGeometry<D>,
    node: &[usize; D],
    mut f: impl FnMut(usize),
) {
    for d in 0..D {
        let mut idx = *node;
        if node[d] >= 1 {
            idx[d] = node[d] - 1;
            f(geo.flat(&idx));
        }
        if node[d] + 1 < geo.nodes[d] {
            idx[d] = node[d] + 1;
            f(geo.flat(&idx));
        }
    }
}

/// Calls `f` with the flat index of each of the 3^D - 1 nodes around `node` that lie in the
/// padded grid.
#[inline]
fn for_each_neighbour<const D: usize>(
    geo: &GridGeometry<D>,
    node: &[usize; D],
    mut f: impl FnMut(usize),
) {
    let count = 3usize.pow(D as u32);
    for k in (0..count).filter(|&k| k != (count - 1) / 2) {
        let mut idx = *node;
        let mut rem = k;
        let mut valid = true;
        for d in 0..D {
            let n = node[d] + rem % 3;
            rem /= 3;
            valid &= n >= 1 && n - 1 < geo.nodes[d];
            idx[d] = n.wrapping_sub(1);
        }
        if valid {
            f(geo.flat(&idx));
        }
    }
}

/// The ghost-fluid share theta of the segment from fluid node i (phi_i < 0) to node j that
/// lies in the fluid: the linear crossing of phi, bounded below by [`THETA_MIN`]; 1 when j is
/// not outside the fluid.
#[inline]
pub fn theta(phi_i: f64, phi_j: f64) -> f64 {
    if phi_j > 0.0 && phi_i < 0.0 {
        (phi_i / (phi_i - phi_j)).max(THETA_MIN)
    } else {
        1.0
    }
}

/// Ghost values on the free-surface nodes after a solve: each is the linear extrapolation
/// p_j = p_i + (d_j - p_i) / theta_ij from the unknowns i around it (the 3^D neighbours), which
/// puts the surface value d_j where phi crosses zero, averaged with the weights theta_ij (a
/// crossing near the fluid node extrapolates far and counts least). `p` holds the unknowns'
/// solution and the surface values d_j on entry; the corrector then takes the gradient of a
/// pressure that is linear across the surface, not one clamped to zero on whole nodes.
///
/// A second layer follows for the wider shape functions: a free-surface node with no unknown
/// among its neighbours continues the line from an unknown m through a neighbour j of the first
/// layer, 2 p_j - p_m, averaged over such lines. `first` is scratch for the first layer; the
/// result is in `out`.
pub fn ghost_values<const D: usize>(
    geo: &GridGeometry<D>,
    kinds: &[NodeKind],
    phi: &[f64],
    p: &[f64],
    out: &mut Vec<f64>,
    first: &mut Vec<f64>,
) {
    pages::copy(first, p);
    first.par_iter_mut().enumerate().for_each(|(j, pj)| {
        if kinds[j] != NodeKind::FreeSurface || phi[j] <= 0.0 {
            return;
        }
        let (mut num, mut den) = (0.0, 0.0);
        for_each_neighbour(geo, &geo.multi(j), |i| {
            let i = geo.canonical(i);
            if kinds[i] == NodeKind::Interior {
                let t = theta(phi[i], phi[j]);
                num += t * p[i] + p[j] - p[i];
                den += t;
            }
        });
        if den > 0.0 {
            *pj = num / den;
        }
    });
    // a second layer, where the wider shape functions reach: a free-surface node with no
    // unknown beside it continues the line from an unknown m through a neighbour j,
    // 2 p_j - p_m (left at the surface value, a node of a quadratic B-spline a cell and a
    // half above a flat surface kept the gradient of the particles below it a half short,
    // and a pool at rest sank into itself)
    pages::copy(out, first);
    let first = &first[..];
    out.par_iter_mut().enumerate().for_each(|(k, pk)| {
        if kinds[k] != NodeKind::FreeSurface || phi[k] <= 0.0 {
            return;
        }
        let node = geo.multi(k);
        let mut reached = false;
        for_each_neighbour(geo, &node, |j| {
            reached |= kinds[geo.canonical(j)] == NodeKind::Interior;
        });
        if reached {
            return;
        }
        let (mut sum, mut count) = (0.0, 0usize);
        for_each_neighbour(geo, &node, |j| {
            if kinds[geo.canonical(j)] != NodeKind::FreeSurface {
                return;
            }
            let jn = geo.multi(j);
            let mut m = jn;
            for d in 0..D {
                let md = 2 * jn[d] as isize - node[d] as isize;
                if md < 0 || md >= geo.nodes[d] as isize {
                    return;
                }
                m[d] = md as usize;
            }
            let m = geo.canonical(geo.flat(&m));
            if kinds[m] == NodeKind::Interior {
                sum += 2.0 * first[geo.canonical(j)] - p[m];
                count += 1;
            }
        });
        if count > 0 {
            *pk = sum / count as f64;
        }
    });
}

/// The pressure a traction-free surface carries, p = n . tau . n, at every free-surface node
/// (0 elsewhere). The boundary condition of a free surface is sigma n = 0 with
/// sigma = -p I + tau; its normal part is p = n . tau . n. For a fluid tau is small there and
/// p = 0 is the usual condition; a solid carries a deviatoric stress up to its surface (the free
/// side of a column under its own weight has p = tau_xx = rho g (H - y) / 2), and p = 0 there
/// would leave a layer of nodes with neither the pressure nor the volume constraint.
///
/// The outward normal is -grad(phi) of the volume fractions of the 2^D cells around the node
/// (cells beyond a closed wall full, beyond an open face empty, as in [`classify`]); tau at the
/// node is the particles' tau averaged with the weights V_p N_ip: the particles are `points`
/// (binned in `bins`) of volumes `volume` and stresses `tau`; the surface is the cells' volume
/// fractions, which faces are open, and the nodes' kinds.
pub(crate) fn surface_normal_stress<const D: usize>(
    points: crate::transfer::Points<D>,
    bins: &CellBins,
    (volume, tau): (&[f64], &[crate::particles::Matrix<D>]),
    (fraction, open, kinds): (&[f64], &[bool], &[NodeKind]),
    out: &mut Vec<f64>,
) {
    let (geo, shape, x, half_width) = (points.geo, points.shape, points.x, points.half_width);
    use crate::grid::Vector;
    use crate::particles::Matrix;
    pages::fit(out, geo.node_count());
    out.par_iter_mut().enumerate().for_each(|(i, pn)| {
        pages::store(pn, 0.0);
        if kinds[i] != NodeKind::FreeSurface {
            return;
        }
        let node = geo.multi(i);
        let mut grad = Vector::<D>::zeros();
        for corner in 0..(1usize << D) {
            let phi = match corner_cell(geo, &node, corner, open) {
                Corner::Cell(c) => fraction[c].min(1.0),
                Corner::Closed => 1.0,
                Corner::Open => 0.0,
            };
            for d in 0..D {
                grad[d] += if (corner >> d) & 1 == 1 { phi } else { -phi };
            }
        }
        let norm = grad.norm();
        if norm == 0.0 {
            return;
        }
        let n = -grad / norm;
        let (mut t, mut w) = (Matrix::<D>::zeros(), 0.0);
        geo.for_each_image(&node, |image| {
            super::assemble::for_particles_near(geo, bins, shape, &image, |p| {
                let xc = geo.to_cells(&x[p]);
                let mut nw = volume[p];
                for d in 0..D {
                    nw *= shape.weight_1d(xc[d], half_width[p], image[d]);
                }
                if nw != 0.0 {
                    t += tau[p] * nw;
                    w += nw;
                }
            });
        });
        if w > 0.0 {
            *pn = n.dot(&(t * n)) / w;
        }
    });
}

/// Work buffers of [`close_bubbles`], kept between steps.
#[derive(Debug, Default)]
pub struct FloodFill {
    /// Per cell: [`UNSEEN`], [`SEEN`] or [`LARGE`] (written only where a fill reached, so the
    /// air's pages stay uncommitted).
    seen: Vec<u8>,
    component: Vec<usize>,
    stack: Vec<usize>,
}

/// A cell no fill has reached ([`FloodFill::seen`]).
const UNSEEN: u8 = 0;
/// A cell of the fill under way, or of a finished one that was closed.
const SEEN: u8 = 1;
/// A low cell of a set too large to close, or that reaches an open face.
const LARGE: u8 = 2;

/// Closes bubbles: every face-connected set of cells at or below the volume-fraction tolerance
/// that has at most `max_cells` cells and does not reach an open face gets the fraction 1
/// (written to `out`; other cells keep their fraction). Such a set enclosed by fluid is a gap
/// between particles that the flow has spread apart, not air: left open, its nodes become
/// p = 0 nodes inside the fluid, the pressure around them collapses for a step and rebounds
/// the next.
///
/// A fill starts only from a low cell beside a cell above the tolerance (every low set but
/// that of a grid with no such cell at all holds one), and stops once its set has grown past
/// `max_cells` cells or reached an open face or a set known to be too large; that set's cells
/// are marked too large, so a later fill that meets them stops too. The air above the water
/// is then visited only a few cells deep along the surface, and `out` is written only where it
/// changes: the fill's work and memory follow the water, not the box.
pub fn close_bubbles<const D: usize>(
    geo: &GridGeometry<D>,
    fraction: &[f64],
    tolerance: f64,
    open: &[bool],
    max_cells: usize,
    scratch: &mut FloodFill,
    out: &mut Vec<f64>,
) {
    pages::copy(out, fraction);
    let FloodFill {
        seen,
        component,
        stack,
    } = scratch;
    pages::fit(seen, fraction.len());
    pages::reset(seen);
    // the face neighbour of cell `c` (multi-index `idx`) along axis `d` (side 0 below, 1
    // above): Ok(cell), or Err(whether that face is open) past the grid's edge
    let neighbour_at = |mut idx: [usize; D], d: usize, side: usize| -> Result<usize, bool> {
        let mut n = idx[d] as isize + if side == 0 { -1 } else { 1 };
        if geo.periodic[d] {
            n = PAD as isize + (n - PAD as isize).rem_euclid(geo.cells[d] as isize);
        }
        if n < PAD as isize || n >= (PAD + geo.cells[d]) as isize {
            return Err(open[2 * d + side]);
        }
        idx[d] = n as usize;
        Ok(geo.flat(&idx))
    };
    let neighbour = |c: usize, d: usize, side: usize| neighbour_at(geo.multi(c), d, side);
    let low = |c: usize| fraction[c] <= tolerance;
    let inside = |idx: &[usize; D]| (0..D).all(|d| idx[d] >= PAD && idx[d] < PAD + geo.cells[d]);
    let beside_fluid = |idx: [usize; D]| {
        (0..D).any(|d| (0..2).any(|side| neighbour_at(idx, d, side).is_ok_and(|f| !low(f))))
    };
    // (the cells in flat order, their multi-indices kept without a division a cell)
    let mut next = [0; D];
    for start in 0..fraction.len() {
        let idx = next;
        geo.advance(&mut next);
        if seen[start] != UNSEEN || !low(start) || !inside(&idx) {
            continue;
        }
        if !beside_fluid(idx) {
            continue;
        }
        // flood fill the low cells connected to `start` through faces
        component.clear();
        stack.clear();
        stack.push(start);
        seen[start] = SEEN;
        let mut large = false;
        'fill: while let Some(c) = stack.pop() {
            component.push(c);
            if component.len() > max_cells {
                large = true;
                break;
            }
            for d in 0..D {
                for side in 0..2 {
                    match neighbour(c, d, side) {
                        Err(true) => large = true,
                        Err(false) => {}
                        Ok(f) if seen[f] == LARGE => large = true,
                        Ok(f) if seen[f] == UNSEEN && low(f) => {
                            seen[f] = SEEN;
                            stack.push(f);
                        }
                        Ok(_) => {}
                    }
                    if large {
                        break 'fill;
                    }
                }
            }
        }
        if large {
            for &c in component.iter().chain(stack.iter()) {
                seen[c] = LARGE;
            }
        } else {
            for &c in component.iter() {
                out[c] = 1.0;
            }
        }
    }
}

/// Fills (fraction 1) every cell inside the grid at or below `tolerance` whose two face
/// neighbours along some axis are both above it: a crack one cell wide between particles
/// that have bunched on either side, not air. Left open, its nodes hold p = 0 inside the
/// water, and the correction that would spread the particles back into it cannot (a column
/// of such cells opened beside the back wall of a collapsing column). A cell past face f
/// counts as full where `behind[f]` (a closed face, not a ceiling: [`Surface::set_ceilings`]),
/// as empty otherwise. The cells are found first and filled after, so a gap two cells
/// across in every direction stays open. `cracks` is scratch.
pub fn close_cracks<const D: usize>(
    geo: &GridGeometry<D>,
    tolerance: f64,
    behind: &[bool],
    fraction: &mut [f64],
    cracks: &mut Vec<usize>,
) {
    let inside = |idx: &[usize; D]| (0..D).all(|d| idx[d] >= PAD && idx[d] < PAD + geo.cells[d]);
    let full = |idx: &[usize; D], d: usize, side: usize, fraction: &[f64]| {
        let n = idx[d] as isize + if side == 0 { -1 } else { 1 };
        let n = if geo.periodic[d] {
            PAD as isize + (n - PAD as isize).rem_euclid(geo.cells[d] as isize)
        } else {
            n
        };
        if n < PAD as isize || n >= (PAD + geo.cells[d]) as isize {
            return behind[2 * d + side];
        }
        let mut m = *idx;
        m[d] = n as usize;
        fraction[geo.flat(&m)] > tolerance
    };
    cracks.clear();
    let mut next = [0; D];
    for (c, &f) in fraction.iter().enumerate() {
        let idx = next;
        geo.advance(&mut next);
        if f > tolerance || !inside(&idx) {
            continue;
        }
        if (0..D).any(|d| full(&idx, d, 0, fraction) && full(&idx, d, 1, fraction)) {
            cracks.push(c);
        }
    }
    for &c in cracks.iter() {
        fraction[c] = 1.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Vector;

    /// A 6 x 6 cell box, particles (2 x 2 per cell) filling `filled(cell)` cells.
    fn setup(filled: impl Fn(usize, usize) -> bool, open: [bool; 4]) -> Vec<NodeKind> {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [6, 6]);
        let mut x = Vec::new();
        for cy in 0..6 {
            for cx in 0..6 {
                if filled(cx, cy) {
                    for (a, b) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                        x.push(Vector::<2>::new(cx as f64 + a, cy as f64 + b));
                    }
                }
            }
        }
        let volume = vec![0.25; x.len()];
        let mut bins = CellBins::default();
        bins.sort(&geo, &x);
        let mut vf = Vec::new();
        volume_fractions(&geo, &bins, &volume, &mut vf);
        // linear-shape mass: every corner node of a filled cell
        let mut mass = vec![0.0; geo.node_count()];
        for p in &x {
            let c = geo.multi(geo.cell_of(p));
            for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                mass[geo.flat(&[c[0] + a, c[1] + b])] += 1.0;
            }
        }
        let mut kinds = Vec::new();
        classify(&geo, &mass, 1e-9, &vf, 0.3, &open, &mut kinds);
        kinds
    }

    fn kind_at(kinds: &[NodeKind], i: usize, j: usize) -> NodeKind {
        // 6 cells + 1 + 2 * PAD nodes per direction
        kinds[(j + PAD) * 11 + i + PAD]
    }

    #[test]
    fn column_against_walls_has_its_top_row_free() {
        // a column 3 cells wide, 4 high, in the box's lower-left corner
        let k = setup(|cx, cy| cx < 3 && cy < 4, [false; 4]);
        for j in 0..=4 {
            for i in 0..=3 {
                let want = if j == 4 || i == 3 {
                    NodeKind::FreeSurface
                } else {
                    NodeKind::Interior
                };
                assert_eq!(kind_at(&k, i, j), want, "node ({i}, {j})");
            }
        }
        assert_eq!(kind_at(&k, 4, 0), NodeKind::Empty);
        assert_eq!(kind_at(&k, 0, 5), NodeKind::Empty);
    }

    /// The air's lines of nodes, set to h whole ([`dry_line`]), hold what each node's own
    /// corners give ([`level_at`]), next to open faces, closed walls and across a periodic
    /// axis alike: a few cells of fluid scattered in a 3D box, the whole box compared.
    #[test]
    fn the_level_set_of_dry_lines_is_each_nodes() {
        let geo = GridGeometry::<3>::new(Vector::<3>::zeros(), 0.5, [7, 5, 6])
            .with_periodic([false, true, false]);
        let mut fraction = vec![0.0; geo.node_count()];
        let cells = [
            [0, 0, 0],
            [6, 4, 5],
            [3, 2, 2],
            [2, 0, 5],
            [0, 4, 3],
            [5, 2, 0],
        ];
        for (k, c) in cells.iter().enumerate() {
            let idx = [c[0] + PAD, c[1] + PAD, c[2] + PAD];
            fraction[geo.flat(&idx)] = 0.3 + 0.1 * k as f64;
        }
        for open in [[false; 6], [true, false, false, false, false, true]] {
            let mut phi = Vec::new();
            level_set(
                &geo,
                (&fraction, None),
                &open,
                None,
                &mut phi,
                &mut Vec::new(),
            );
            for i in 0..geo.node_count() {
                let node = geo.multi(i);
                let own = level_at(&geo, (&fraction, None), &open, &node);
                assert_eq!(phi[i], own, "node {node:?}, open faces {open:?}");
            }
            let h_nodes = phi.iter().filter(|&&p| p == geo.h).count();
            assert!(h_nodes > 0 && h_nodes < geo.node_count());
        }
    }

    /// The level set of a column 3 cells wide and 4 high in the lower-left corner of a closed
    /// 6 x 6 box (2 x 2 particles per filled cell): the signed distance to its top and side
    /// within a cell of them, the walls read as mirrors; and a rigid block beside the column
    /// is no free surface.
    #[test]
    fn level_set_of_a_column_is_its_signed_distance() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [6, 6]);
        let mut x = Vec::new();
        for cy in 0..4 {
            for cx in 0..3 {
                for (a, b) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    x.push(Vector::<2>::new(cx as f64 + a, cy as f64 + b));
                }
            }
        }
        let mut bins = CellBins::default();
        bins.sort(&geo, &x);
        let mut vf = Vec::new();
        volume_fractions(&geo, &bins, &vec![0.25; x.len()], &mut vf);
        let at = |phi: &[f64], i: usize, j: usize| phi[geo.flat(&[i + PAD, j + PAD])];
        let mut phi = Vec::new();
        level_set(
            &geo,
            (&vf, None),
            &[false; 4],
            None,
            &mut phi,
            &mut Vec::new(),
        );
        // the top (y = 4) and the side (x = 3): on the surface; a cell inside and outside
        for i in 0..3 {
            assert_eq!(at(&phi, i, 4), 0.0, "top, node {i}");
            assert_eq!(at(&phi, i, 3), -1.0, "below the top, node {i}");
            assert_eq!(at(&phi, i, 5), 1.0, "above the top, node {i}");
        }
        for j in 0..4 {
            assert_eq!(at(&phi, 3, j), 0.0, "side, node {j}");
            assert_eq!(at(&phi, 4, j), 1.0, "beside the side, node {j}");
        }
        // the walls mirror the fluid: the corner where the top meets the wall is on the surface
        assert_eq!(at(&phi, 0, 4), 0.0);
        assert_eq!(at(&phi, 0, 1), -1.0);
        // a rigid block filling the cells beside the column (x in [3, 6], y in [0, 2]): the
        // water against it is inside, the top above it still a surface
        let mut solid = vec![0.0; geo.node_count()];
        for cy in 0..2 {
            for cx in 3..6 {
                solid[geo.flat(&[cx + PAD, cy + PAD])] = 1.0;
            }
        }
        level_set(
            &geo,
            (&vf, Some(&solid)),
            &[false; 4],
            None,
            &mut phi,
            &mut Vec::new(),
        );
        assert_eq!(at(&phi, 3, 1), -1.0, "water against the block");
        assert_eq!(at(&phi, 3, 3), 0.0, "the side above the block");
    }

    /// A rigid body that leaves only slivers of its cells open: a node inside its face reads
    /// the water against the face from its neighbours, not from the slivers, which hold no
    /// particle (read on their own they put the node in the air).
    #[test]
    fn a_node_inside_a_face_reads_the_water_beside_it() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [6, 6]);
        // water fills the cells x < 3; a body covers 0.9 of every cell x >= 3, without water
        let (mut vf, mut solid) = (vec![0.0; geo.node_count()], vec![0.0; geo.node_count()]);
        for cy in 0..6 {
            for cx in 0..6 {
                let c = geo.flat(&[cx + PAD, cy + PAD]);
                if cx < 3 {
                    vf[c] = 1.0;
                } else {
                    solid[c] = 0.9;
                }
            }
        }
        let at = |phi: &[f64], i: usize, j: usize| phi[geo.flat(&[i + PAD, j + PAD])];
        let mut phi = Vec::new();
        level_set(
            &geo,
            (&vf, Some(&solid)),
            &[false; 4],
            None,
            &mut phi,
            &mut Vec::new(),
        );
        // the face's node x = 3: its open room is 2.2 cells, 2 of them water
        let face = 1.0 - 2.0 * 2.0 / 2.2;
        assert!((at(&phi, 3, 2) - face).abs() < 1e-12, "{}", at(&phi, 3, 2));
        // x = 4, 0.4 cells of room, all of it dry: the face's value, not +1
        assert_eq!(at(&phi, 4, 2), at(&phi, 3, 2));
        // deeper, no neighbour with room: its own slivers, dry
        assert_eq!(at(&phi, 5, 2), 1.0);
    }

    /// The pressure reaches two layers of nodes into a rigid body, as their neighbours' mean.
    #[test]
    fn a_field_extends_two_layers_into_a_solid() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [8, 4]);
        let n = geo.node_count();
        let (mut kinds, mut field) = (vec![NodeKind::Empty; n], vec![0.0; n]);
        for j in 0..geo.nodes[1] {
            for i in 0..geo.nodes[0] {
                let k = geo.flat(&[i, j]);
                if i <= 3 + PAD {
                    (kinds[k], field[k]) = (NodeKind::Interior, 10.0 + j as f64);
                } else {
                    (kinds[k], field[k]) = (NodeKind::Solid, -1.0);
                }
            }
        }
        extend_into_solids(&geo, &kinds, &mut field, &mut Vec::new());
        let j = 2 + PAD;
        let at = |i: usize, j: usize| field[geo.flat(&[i + PAD, j])];
        // the first layer: the mean of its three water neighbours, 10 + j
        assert!((at(4, j) - (10.0 + j as f64)).abs() < 1e-12, "{}", at(4, j));
        // the second: the mean of the first layer's three
        assert!((at(5, j) - (10.0 + j as f64)).abs() < 1e-12, "{}", at(5, j));
        // no further
        assert_eq!(at(6, j), 0.0);
    }

    #[test]
    fn filled_closed_box_has_no_free_surface_but_an_open_face_does() {
        let k = setup(|_, _| true, [false; 4]);
        assert!(k.iter().all(|&n| n != NodeKind::FreeSurface));
        let k = setup(|_, _| true, [false, false, false, true]);
        for i in 0..=6 {
            assert_eq!(kind_at(&k, i, 6), NodeKind::FreeSurface);
            assert_eq!(kind_at(&k, i, 5), NodeKind::Interior);
        }
    }

    #[test]
    fn a_drop_and_a_cavity_are_free_surfaces() {
        // a filled box with one empty cell (a bubble) at (2, 2) and a lone filled cell (a
        // drop) cannot exist together; test the bubble in a full box
        let k = setup(|cx, cy| !(cx == 2 && cy == 2), [false; 4]);
        for (i, j) in [(2, 2), (3, 2), (2, 3), (3, 3)] {
            assert_eq!(kind_at(&k, i, j), NodeKind::FreeSurface);
        }
        assert_eq!(kind_at(&k, 1, 1), NodeKind::Interior);
        assert_eq!(kind_at(&k, 4, 4), NodeKind::Interior);
        // a splash: one filled cell in mid-air above a filled floor layer
        let k = setup(|cx, cy| cy == 0 || (cx == 3 && cy == 4), [false; 4]);
        for (i, j) in [(3, 4), (4, 4), (3, 5), (4, 5)] {
            assert_eq!(kind_at(&k, i, j), NodeKind::FreeSurface);
        }
        assert_eq!(kind_at(&k, 2, 0), NodeKind::Interior);
        assert_eq!(kind_at(&k, 2, 1), NodeKind::FreeSurface);
    }

    #[test]
    fn sparse_cells_below_the_tolerance_are_not_filled() {
        // one particle in a cell: volume fraction 0.25 < 0.3
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [2, 2]);
        let x = vec![Vector::<2>::new(0.5, 0.5)];
        let mut bins = CellBins::default();
        bins.sort(&geo, &x);
        let mut vf = Vec::new();
        volume_fractions(&geo, &bins, &[0.25], &mut vf);
        assert!((vf[geo.cell_of(&x[0])] - 0.25).abs() < 1e-15);
        let mass = vec![1.0; geo.node_count()];
        let mut kinds = Vec::new();
        classify(&geo, &mass, 1e-9, &vf, 0.3, &[false; 4], &mut kinds);
        assert_eq!(kinds[geo.flat(&[PAD, PAD])], NodeKind::FreeSurface);
        classify(&geo, &mass, 1e-9, &vf, 0.2, &[false; 4], &mut kinds);
        // the corner node at the walls sees only the one (now filled) cell and the walls
        assert_eq!(kinds[geo.flat(&[PAD, PAD])], NodeKind::Interior);
    }

    /// `pressure.volume_fraction_tolerance` is what the paper's rule compares with: the same
    /// cell, a quarter full, is air under 0.3 and water under 0.2, through `Surface::detect`.
    #[test]
    fn the_paper_rule_reads_the_decks_tolerance() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [2, 2]);
        let x = vec![Vector::<2>::new(0.5, 0.5)];
        let mut bins = CellBins::default();
        bins.sort(&geo, &x);
        let mass = vec![1.0; geo.node_count()];
        let corner = geo.flat(&[PAD, PAD]);
        for (tolerance, kind) in [(0.3, NodeKind::FreeSurface), (0.2, NodeKind::Interior)] {
            let mut s =
                Surface::with_settings(FreeSurface::VolumeFraction, tolerance, 0, vec![false; 4]);
            let rigid = crate::rigid::RigidBodies::<2>::default();
            s.detect(&geo, &bins, &[0.25], &mass, 1e-9, &rigid);
            assert_eq!(s.kinds[corner], kind, "tolerance {tolerance}");
        }
    }

    /// Fractions of a 6 x 6 box: `f(cx, cy)` per cell.
    fn fractions(geo: &GridGeometry<2>, f: impl Fn(usize, usize) -> f64) -> Vec<f64> {
        let mut vf = vec![0.0; geo.node_count()];
        for cy in 0..geo.cells[1] {
            for cx in 0..geo.cells[0] {
                vf[geo.flat(&[cx + PAD, cy + PAD])] = f(cx, cy);
            }
        }
        vf
    }

    #[test]
    fn over_ranks_a_window_cell_takes_its_gap_closed_as_its_owner_closed_it() {
        use crate::comm::{threads, Comm};
        use crate::slabs::{Decomposition, Sliced};
        use std::sync::Arc;
        // 12 x 40 cells of water cut along y at cell row 20 for two ranks, a window of 8
        // rows; a gap of 6 cells up x = 5 from row 25 to 30. Rank 0's window ends at row 27:
        // its part of the gap runs into the empty rows past the window and reads as open
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [12, 40]);
        let gap = |cx: usize, cy: usize| cx == 5 && (25..31).contains(&cy);
        let whole = fractions(&geo, |cx, cy| if gap(cx, cy) { 0.0 } else { 1.0 });
        let (low, bound) = (0.3, 8);
        let mut one = Vec::new();
        close_bubbles(
            &geo,
            &whole,
            low,
            &[false; 4],
            bound,
            &mut FloodFill::default(),
            &mut one,
        );
        let at = |v: &[f64], cx: usize, cy: usize| v[geo.flat(&[cx + PAD, cy + PAD])];
        assert!(
            (25..31).all(|cy| at(&one, 5, cy) == 1.0),
            "one process closes the gap"
        );
        let w = 8;
        let d = Decomposition {
            axis: 1,
            cuts: vec![0, 20 + PAD, geo.nodes[1]],
            window: w,
            reach: crate::slabs::WIDEST_REACH,
        };
        let out = threads::run(2, |world| {
            let r = world.rank();
            let (lo, hi) = (d.cuts[r], d.cuts[r + 1]);
            let view = lo.saturating_sub(w)..(hi + w).min(geo.nodes[1]);
            // the fractions on its view: its slab's own and the window's from their owners
            let seen: Vec<f64> = (0..geo.node_count())
                .map(|c| {
                    if view.contains(&geo.multi(c)[1]) {
                        whole[c]
                    } else {
                        0.0
                    }
                })
                .collect();
            let mut closed = Vec::new();
            close_bubbles(
                &geo,
                &seen,
                low,
                &[false; 4],
                bound,
                &mut FloodFill::default(),
                &mut closed,
            );
            let alone = closed.clone();
            let comm: Arc<dyn Comm> = Arc::new(Sliced::new(world, &geo, &d));
            let owners = Owners {
                comm,
                axis: 1,
                layers: lo..hi,
                reach: d.reach,
            };
            take_owners(&geo, &owners, &mut closed, false);
            // the closed fractions come from their owners as deep as the stages read
            let reach = d.sums_window();
            let read = lo.saturating_sub(reach)..(hi + reach).min(geo.nodes[1]);
            (alone, closed, read)
        });
        assert_eq!(
            at(&out[0].0, 5, 25),
            0.0,
            "rank 0 alone leaves its part open"
        );
        for (_, closed, view) in &out {
            for c in (0..geo.node_count()).filter(|&c| view.contains(&geo.multi(c)[1])) {
                assert_eq!(closed[c], one[c], "cell {:?}", geo.multi(c));
            }
        }
    }

    #[test]
    fn small_enclosed_bubbles_close_and_air_stays_open() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [6, 6]);
        // water in the lower 4 rows with a one-cell and a two-cell gap, air above
        let vf = fractions(&geo, |cx, cy| match (cx, cy) {
            (1, 1) | (3, 2) | (4, 2) => 0.0,
            (_, y) if y < 4 => 1.0,
            _ => 0.0,
        });
        let mut out = Vec::new();
        let mut ff = FloodFill::default();
        close_bubbles(&geo, &vf, 0.3, &[false; 4], 2, &mut ff, &mut out);
        let at = |v: &[f64], cx: usize, cy: usize| v[geo.flat(&[cx + PAD, cy + PAD])];
        for (cx, cy) in [(1, 1), (3, 2), (4, 2)] {
            assert_eq!(at(&out, cx, cy), 1.0, "gap ({cx}, {cy})");
        }
        // the air above (12 cells) is not a bubble
        assert!((0..6).all(|cx| at(&out, cx, 4) == 0.0 && at(&out, cx, 5) == 0.0));
        // a bubble larger than the bound stays open
        close_bubbles(&geo, &vf, 0.3, &[false; 4], 1, &mut ff, &mut out);
        assert_eq!(at(&out, 1, 1), 1.0);
        assert_eq!(at(&out, 3, 2), 0.0);
        // a gap that reaches an open face is air
        let vf = fractions(&geo, |cx, cy| if (cx, cy) == (5, 3) { 0.0 } else { 1.0 });
        close_bubbles(
            &geo,
            &vf,
            0.3,
            &[false, true, false, false],
            4,
            &mut ff,
            &mut out,
        );
        assert_eq!(at(&out, 5, 3), 0.0);
        close_bubbles(&geo, &vf, 0.3, &[false; 4], 4, &mut ff, &mut out);
        assert_eq!(at(&out, 5, 3), 1.0);
    }

    #[test]
    fn a_fill_stopped_by_the_bound_leaves_the_rest_of_its_gap_open() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [12, 12]);
        // water in the lower 6 rows with a gap of 4 cells in a row (row 2, columns 3 to 6),
        // air above
        let vf = fractions(&geo, |cx, cy| match (cx, cy) {
            (3..=6, 2) => 0.0,
            (_, y) if y < 6 => 1.0,
            _ => 0.0,
        });
        let at = |v: &[f64], cx: usize, cy: usize| v[geo.flat(&[cx + PAD, cy + PAD])];
        let (mut out, mut ff) = (Vec::new(), FloodFill::default());
        // the first fill stops after 3 cells; the fill from the fourth meets them and stops
        close_bubbles(&geo, &vf, 0.3, &[false; 4], 2, &mut ff, &mut out);
        assert!((3..=6).all(|cx| at(&out, cx, 2) == 0.0));
        close_bubbles(&geo, &vf, 0.3, &[false; 4], 4, &mut ff, &mut out);
        assert!((3..=6).all(|cx| at(&out, cx, 2) == 1.0));
        // the fills reach only the air next to the surface: at most one stopped fill's cells
        // (max_cells + 1, the stack's at most 2 D more each) per surface cell
        let reached = ff.seen.iter().filter(|&&s| s != UNSEEN).count();
        assert!(reached < 6 * 12, "{reached} cells reached");
        assert!((0..12).all(|cx| ff.seen[geo.flat(&[cx + PAD, 11 + PAD])] == UNSEEN));
    }

    #[test]
    fn a_crack_one_cell_wide_closes_and_the_surface_and_wider_gaps_stay() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [8, 8]);
        // water in the lower 6 rows: a crack one cell wide (column 2, rows 0 to 4), a gap two
        // cells across both ways (columns 5 and 6, rows 2 and 3), air above
        let vf = fractions(&geo, |cx, cy| match (cx, cy) {
            (2, y) if y < 5 => 0.1,
            (5, 2) | (6, 2) | (5, 3) | (6, 3) => 0.0,
            (_, y) if y < 6 => 1.0,
            _ => 0.0,
        });
        let mut out = vf.clone();
        let mut scratch = Vec::new();
        close_cracks(&geo, 0.5, &[true; 4], &mut out, &mut scratch);
        let at = |v: &[f64], cx: usize, cy: usize| v[geo.flat(&[cx + PAD, cy + PAD])];
        assert!((0..5).all(|cy| at(&out, 2, cy) == 1.0));
        assert_eq!((at(&out, 5, 2), at(&out, 6, 2)), (0.0, 0.0));
        assert!((0..8).all(|cx| at(&out, cx, 6) == 0.0 && at(&out, cx, 7) == 0.0));
        // a cell against the x_max face: closed vertically by the water above and below it;
        // three such cells in a column close against a closed face, not an open one
        let after = |gap: &[(usize, usize)], behind: [bool; 4]| {
            let mut out = fractions(&geo, |cx, cy| match (cx, cy) {
                c if gap.contains(&c) => 0.0,
                (_, y) if y < 6 => 1.0,
                _ => 0.0,
            });
            close_cracks(&geo, 0.5, &behind, &mut out, &mut Vec::new());
            at(&out, 7, 3)
        };
        let east_open = [true, false, true, true];
        assert_eq!(after(&[(7, 3)], east_open), 1.0);
        assert_eq!(after(&[(7, 2), (7, 3), (7, 4)], east_open), 0.0);
        assert_eq!(after(&[(7, 2), (7, 3), (7, 4)], [true; 4]), 1.0);
    }

    /// A row of cells emptied under a closed lid (water below it, gravity down) is water
    /// falling away: it stays open; the same row over a closed floor, gravity up, too; with
    /// gravity along x both are cracks.
    #[test]
    fn a_gap_under_a_ceiling_is_no_crack() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [4, 4]);
        let gap = |row: usize, gravity: [f64; 2]| {
            let mut s = Surface::with_settings(FreeSurface::LevelSet, 0.5, 0, vec![false; 4]);
            s.set_ceilings(&gravity);
            let mut out = fractions(&geo, |_, cy| if cy == row { 0.0 } else { 1.0 });
            close_cracks(&geo, 0.5, &s.behind, &mut out, &mut Vec::new());
            (0..4)
                .map(|cx| out[geo.flat(&[cx + PAD, row + PAD])])
                .sum::<f64>()
        };
        assert_eq!(gap(3, [0.0, -9.81]), 0.0);
        assert_eq!(gap(0, [0.0, 9.81]), 0.0);
        assert_eq!(gap(3, [9.81, 0.0]), 4.0);
        assert_eq!(gap(0, [0.0, -9.81]), 4.0);
    }

    #[test]
    fn a_solid_surface_carries_its_normal_stress() {
        // a block of 4 x 4 cells in a 8 x 8 box (closed walls), 2 x 2 particles per cell, all
        // with the same deviatoric stress
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [8, 8]);
        let mut x = Vec::new();
        for cy in 0..4 {
            for cx in 2..6 {
                for (a, b) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    x.push(Vector::<2>::new(cx as f64 + a, cy as f64 + b));
                }
            }
        }
        let n = x.len();
        let volume = vec![0.25; n];
        let tau = vec![crate::particles::Matrix::<2>::new(3.0, 0.5, 0.5, -3.0); n];
        let mut bins = CellBins::default();
        bins.sort(&geo, &x);
        let mut vf = Vec::new();
        volume_fractions(&geo, &bins, &volume, &mut vf);
        let mass: Vec<f64> = (0..geo.node_count())
            .map(|i| {
                let m = geo.multi(i);
                let (i, j) = (m[0] as isize - PAD as isize, m[1] as isize - PAD as isize);
                if (2..=6).contains(&i) && (0..=4).contains(&j) {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let open = [false; 4];
        let mut kinds = Vec::new();
        classify(&geo, &mass, 1e-9, &vf, 0.3, &open, &mut kinds);
        let mut p = Vec::new();
        let half = vec![0.0; n];
        let points = crate::transfer::Points {
            geo: &geo,
            shape: crate::shape::ShapeFunction::Linear,
            x: &x,
            half_width: &half,
        };
        surface_normal_stress(points, &bins, (&volume, &tau), (&vf, &open, &kinds), &mut p);
        let at = |i: usize, j: usize| geo.flat(&[i + PAD, j + PAD]);
        // the sides (normal -x, +x): tau_xx; the top (normal +y): tau_yy
        for j in 1..=3 {
            assert_eq!(kinds[at(2, j)], NodeKind::FreeSurface);
            assert!(
                (p[at(2, j)] - 3.0).abs() < 1e-12,
                "left side {j}: {}",
                p[at(2, j)]
            );
            assert!((p[at(6, j)] - 3.0).abs() < 1e-12, "right side {j}");
        }
        for i in 3..=5 {
            assert!(
                (p[at(i, 4)] + 3.0).abs() < 1e-12,
                "top {i}: {}",
                p[at(i, 4)]
            );
        }
        // interior nodes carry none (their pressure is the solve's)
        assert_eq!(kinds[at(4, 2)], NodeKind::Interior);
        assert_eq!(p[at(4, 2)], 0.0);
    }

    /// A free-surface node out of reach of every unknown, in a film under a lid and in one on
    /// a floor: the wall nodes hold v_y = 0. The film on the floor, falling into it, takes the
    /// wall's v_y; the one under the lid, falling away from it, keeps its own.
    #[test]
    fn a_wall_stops_a_film_moving_into_it_and_lets_one_fall_off() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [6, 6]);
        let n = geo.node_count();
        let at = |i: usize, j: usize| geo.flat(&[i + PAD, j + PAD]);
        let mut kinds = vec![NodeKind::Empty; n];
        let mut held = vec![0u8; n];
        let mut v = vec![Vector::<2>::zeros(); n];
        for i in 0..=6 {
            for (wall, film) in [(0, 1), (6, 5)] {
                held[at(i, wall)] |= 1 << 1;
                kinds[at(i, wall)] = NodeKind::FreeSurface;
                kinds[at(i, film)] = NodeKind::FreeSurface;
                v[at(i, film)] = Vector::<2>::new(0.3, -0.5);
            }
        }
        let mut scratch = Vec::new();
        extend_velocity(&geo, &kinds, &held, &mut v, &mut scratch);
        for i in 0..=6 {
            assert_eq!(v[at(i, 1)], Vector::<2>::new(0.3, 0.0), "floor film at {i}");
            assert_eq!(v[at(i, 5)], Vector::<2>::new(0.3, -0.5), "lid film at {i}");
        }
    }

    /// A pool 4 cells deep in a closed 6 x 6 box whose two floor cells in the middle hold two
    /// particles each instead of four (the particles drawn apart on the floor): with the level
    /// set, whose surface lies where a node's cells are half full, the node between them would
    /// read as air inside the water; the bubble closing fills them, and every node below the
    /// top keeps its equation.
    #[test]
    fn half_filled_cells_inside_the_water_are_no_surface() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [6, 6]);
        let mut x = Vec::new();
        for cy in 0..4 {
            for cx in 0..6 {
                let thinned = cy == 0 && (cx == 2 || cx == 3);
                for (a, b) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    if !(thinned && b > 0.5) {
                        x.push(Vector::<2>::new(cx as f64 + a, cy as f64 + b));
                    }
                }
            }
        }
        let mut bins = CellBins::default();
        bins.sort(&geo, &x);
        let volume = vec![0.25; x.len()];
        let mut mass = vec![0.0; geo.node_count()];
        for p in &x {
            let c = geo.multi(geo.cell_of(p));
            for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                mass[geo.flat(&[c[0] + a, c[1] + b])] += 1.0;
            }
        }
        let mut surface = Surface::with_settings(FreeSurface::LevelSet, 0.3, 8, vec![false; 4]);
        let rigid = crate::rigid::RigidBodies::<2>::default();
        surface.detect(&geo, &bins, &volume, &mass, 1e-9, &rigid);
        for j in 0..4 {
            for i in 0..=6 {
                assert_eq!(
                    kind_at(&surface.kinds, i, j),
                    NodeKind::Interior,
                    "node ({i}, {j})"
                );
            }
        }
        // without the closing the node between the two cells is a surface node
        surface.bubble_cells = 0;
        surface.detect(&geo, &bins, &volume, &mass, 1e-9, &rigid);
        assert_eq!(kind_at(&surface.kinds, 3, 0), NodeKind::FreeSurface);
    }
}
