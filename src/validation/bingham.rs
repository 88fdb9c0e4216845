//! Bingham plane Poiseuille flow: a yield-stress fluid driven by a body force through a periodic
//! channel, against the ideal Bingham solution with its rigid plug, and against the steady
//! profile of the regularised (Papanastasiou) law that pmpm integrates, so that the error of the
//! method and the error of the regularisation are told apart.
//!
//! The ideal solution (Bird, Dai & Yarusso 1983, Rev. Chem. Eng. 1, 1-70, plane Poiseuille flow
//! of a Bingham plastic; also Bird, Armstrong & Hassager, Dynamics of Polymeric Liquids vol. 1,
//! 2nd ed. 1987, ch. 4): in a channel of half-width H driven by the pressure gradient G (here
//! rho g_x), the momentum balance gives the shear stress tau_xy = -G (y - y_c) whatever the law,
//! so |tau| = G r with r = |y - y_c|. The fluid is rigid where G r < tau_y, r < y0 = tau_y / G,
//! and there du/dr = 0; elsewhere tau_y + mu_p |du/dr| = G r. With u(H) = 0:
//!
//!   u(r) = G / (2 mu_p) (H^2 - r^2) - tau_y / mu_p (H - r)     for y0 <= r <= H,
//!   u(r) = G / (2 mu_p) (H - y0)^2                               for r < y0 (the plug).
//!
//! The regularised law tau = tau_y (1 - exp(-m gamma)) + mu_p gamma has no plug: its steady
//! profile is u(r) = int_r^H gamma(G s) ds with gamma(tau) the inverse of the law, found by
//! Newton's method here. Its gap to the ideal profile is largest at the centre, where it is the
//! area between the two flow curves divided by G: int_0^inf tau_y exp(-m gamma) d gamma / G =
//! tau_y / (G m) = y0 / m (up to exp(-m gamma_wall)); the unit tests check the Newton integral
//! against that closed form.

use super::plot::{colors, save, Panel, Series};
use super::{load_deck, pct, prose, run_deck, sci, Ctx, Row, Section};
use pmpm::deck::Scheme;
use pmpm::particles::Matrix;
use pmpm::scheme::Simulation;

/// A Bingham channel: walls at y = 0 and y = width, body force along x.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Channel {
    /// Channel width W (m).
    pub width: f64,
    /// Density rho (kg/m3).
    pub density: f64,
    /// Body force per unit mass g_x (m/s2).
    pub body_force: f64,
    /// Plastic viscosity mu_p (Pa s).
    pub viscosity: f64,
    /// Yield stress tau_y (Pa).
    pub yield_stress: f64,
    /// Papanastasiou exponent m (s).
    pub exponent: f64,
}

/// The validation case's channel (`validation/decks/bingham_poiseuille.toml`).
pub const CASE: Channel = Channel {
    width: 1.0,
    density: 1.0,
    body_force: 1.0,
    viscosity: 1.0,
    yield_stress: 0.1,
    exponent: 250.0,
};

impl Channel {
    /// Half-width H.
    pub fn half_width(&self) -> f64 {
        0.5 * self.width
    }

    /// The driving pressure gradient G = rho g_x.
    pub fn drive(&self) -> f64 {
        self.density * self.body_force
    }

    /// Half-width y0 = tau_y / G of the ideal plug (H when the fluid does not yield at all).
    pub fn plug_half_width(&self) -> f64 {
        (self.yield_stress / self.drive()).min(self.half_width())
    }

    /// The ideal Bingham profile u(y) (module comment).
    pub fn ideal(&self, y: f64) -> f64 {
        let (h, g, mu) = (self.half_width(), self.drive(), self.viscosity);
        let r = (y - h).abs().min(h).max(self.plug_half_width());
        g / (2.0 * mu) * (h * h - r * r) - self.yield_stress / mu * (h - r)
    }

    /// The ideal plug speed G (H - y0)^2 / (2 mu_p), the peak of the profile.
    pub fn peak(&self) -> f64 {
        self.ideal(self.half_width())
    }

    /// Shear stress of the regularised law at shear rate `gamma` >= 0.
    pub fn regularised_stress(&self, gamma: f64) -> f64 {
        -self.yield_stress * (-self.exponent * gamma).exp_m1() + self.viscosity * gamma
    }

    /// The shear rate at which the regularised law's stress is `tau` >= 0: Newton's method from
    /// gamma = 0. The law is increasing and concave in gamma, so the iterates rise to the root
    /// without overshooting it.
    pub fn regularised_shear_rate(&self, tau: f64) -> f64 {
        let (ty, m, mu) = (self.yield_stress, self.exponent, self.viscosity);
        let mut gamma = 0.0f64;
        for _ in 0..200 {
            let f = self.regularised_stress(gamma) - tau;
            let df = ty * m * (-m * gamma).exp() + mu;
            let next = gamma - f / df;
            if (next - gamma).abs() <= 1e-15 * next.abs().max(1e-300) {
                return next;
            }
            gamma = next;
        }
        gamma
    }

    /// The regularised steady profile at `n + 1` points y = W i / n: u(r) = int_r^H gamma(G s)
    /// ds, by the trapezoidal rule on `4 n` intervals per half-width, n even.
    pub fn regularised(&self, n: usize) -> Vec<(f64, f64)> {
        assert!(
            n % 2 == 0,
            "an even number of intervals puts a point on the centre line"
        );
        let h = self.half_width();
        let fine = 4 * n;
        // u at r_k = H k / fine (half the channel), integrated from the wall inwards
        let ds = h / fine as f64;
        let gamma: Vec<f64> = (0..=fine)
            .map(|k| self.regularised_shear_rate(self.drive() * ds * k as f64))
            .collect();
        let mut u = vec![0.0; fine + 1];
        for k in (0..fine).rev() {
            u[k] = u[k + 1] + 0.5 * (gamma[k] + gamma[k + 1]) * ds;
        }
        (0..=n)
            .map(|i| {
                let y = self.width * i as f64 / n as f64;
                // r = |y - H| = |i - n/2| W / n, and the fine step is H / (4 n) = W / (8 n)
                let k = (i as i64 - (n / 2) as i64).unsigned_abs() as usize * 8;
                (y, u[k.min(fine)])
            })
            .collect()
    }
}

/// sqrt(J2) = sqrt(tau : tau / 2) of a deviatoric stress: the shear stress in simple shear.
fn sqrt_j2<const D: usize>(tau: &Matrix<D>) -> f64 {
    (0.5 * tau.norm_squared()).sqrt()
}

/// One particle row of the final state: mean y, mean u, mean sqrt(J2).
#[derive(Debug, Clone, Copy)]
struct RowState {
    y: f64,
    u: f64,
    sqrt_j2: f64,
}

/// Particle rows (of the initial lattice, h/2 apart), bottom to top.
fn rows(sim: &Simulation<2>, h: f64, width: f64) -> Vec<RowState> {
    let n = (2.0 * width / h).round() as usize;
    let mut sum = vec![(0.0, 0.0, 0.0, 0usize); n];
    let ps = &sim.particles;
    for p in 0..ps.len() {
        let k = ((ps.x[p][1] / (h / 2.0)).floor().max(0.0) as usize).min(n - 1);
        sum[k].0 += ps.x[p][1];
        sum[k].1 += ps.v[p][0];
        sum[k].2 += sqrt_j2(&pmpm::material::deviatoric_stress(ps, &sim.materials, p));
        sum[k].3 += 1;
    }
    sum.iter()
        .filter(|r| r.3 > 0)
        .map(|r| {
            let c = r.3 as f64;
            RowState {
                y: r.0 / c,
                u: r.1 / c,
                sqrt_j2: r.2 / c,
            }
        })
        .collect()
}

/// Width of the unyielded band around the centre line: the rows whose mean sqrt(J2) is below
/// tau_y, taken outwards from the row nearest the centre, each edge placed where sqrt(J2)
/// crosses tau_y between the last unyielded and the first yielded row (linear interpolation).
/// 0 when the row at the centre has yielded.
fn plug_width(rows: &[RowState], centre: f64, tau_y: f64) -> f64 {
    let Some(c) = (0..rows.len()).min_by(|&a, &b| {
        (rows[a].y - centre)
            .abs()
            .total_cmp(&(rows[b].y - centre).abs())
    }) else {
        return 0.0;
    };
    if rows[c].sqrt_j2 >= tau_y {
        return 0.0;
    }
    let edge = |step: isize| {
        let mut k = c as isize;
        loop {
            let next = k + step;
            if next < 0 || next as usize >= rows.len() {
                return rows[k as usize].y;
            }
            let (a, b) = (rows[k as usize], rows[next as usize]);
            if b.sqrt_j2 >= tau_y {
                return a.y + (tau_y - a.sqrt_j2) / (b.sqrt_j2 - a.sqrt_j2) * (b.y - a.y);
            }
            k = next;
        }
    };
    edge(1) - edge(-1)
}

/// What one run gives.
struct RunResult {
    rows: Vec<RowState>,
    /// (t, max row error / peak) during the run.
    history: Vec<(f64, f64)>,
    /// Plug-row speed at end - 0.1 and at the end.
    centre_before: f64,
    centre_end: f64,
    steps: u64,
}

fn run_channel(scheme: Scheme, n: f64, ch: &Channel) -> Result<(RunResult, f64), String> {
    let h = ch.width / n;
    let d = load_deck("bingham_poiseuille", |d| {
        d.simulation.scheme = scheme;
        d.grid.cell_size = h;
        d.grid.size = vec![5.0 * h, ch.width];
        d.bodies[0].shape.max = Some(vec![5.0 * h, ch.width]);
    })?;
    let end = d.simulation.end_time;
    let peak = ch.peak();
    let centre_speed = |sim: &Simulation<2>| {
        let ps = &sim.particles;
        let (mut s, mut c) = (0.0, 0usize);
        for p in 0..ps.len() {
            if (ps.x[p][1] - ch.half_width()).abs() < 0.5 * h {
                s += ps.v[p][0];
                c += 1;
            }
        }
        s / c.max(1) as f64
    };
    let mut history = vec![(0.0, 1.0)];
    let mut next_sample = 0.02;
    let mut centre_before = f64::NAN;
    let sim = run_deck::<2>(&d, |sim, _| {
        if sim.time >= next_sample - 1e-12 {
            let worst = rows(sim, h, ch.width)
                .iter()
                .map(|r| (r.u - ch.ideal(r.y)).abs())
                .fold(0.0, f64::max);
            history.push((sim.time, worst / peak));
            next_sample += 0.02;
        }
        if centre_before.is_nan() && sim.time >= end - 0.1 - 1e-12 {
            centre_before = centre_speed(sim);
        }
        true
    })?;
    Ok((
        RunResult {
            rows: rows(&sim, h, ch.width),
            history,
            centre_before,
            centre_end: centre_speed(&sim),
            steps: sim.steps,
        },
        h,
    ))
}

/// Cells across the channel.
fn cells_across(quick: bool) -> f64 {
    if quick {
        16.0
    } else {
        32.0
    }
}

/// The validation case `bingham_poiseuille`.
pub fn poiseuille(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let n = cells_across(quick);
    let ch = CASE;
    let (peak, y0) = (ch.peak(), ch.plug_half_width());
    let reg = ch.regularised(400);
    let reg_at = |y: f64| {
        super::interp(
            &reg.iter().map(|p| p.0).collect::<Vec<_>>(),
            &reg.iter().map(|p| p.1).collect::<Vec<_>>(),
            y,
        )
    };
    let mut s = Section::default();
    s.rows.push(regularisation_row(&ch, &reg));
    let cells = |v: f64, h: f64| format!("{} ({} h)", sci(v), sci(v / h));
    let (mut profile, mut stress) = reference_series(&ch, &reg);
    let mut history = Vec::new();
    let mut steps_text = Vec::new();
    for (scheme, label, color) in [
        (Scheme::Projection, "projection", colors::PROJ),
        (Scheme::Explicit, "explicit", colors::EXPL),
    ] {
        let (r, h) = run_channel(scheme, n, &ch)?;
        steps_text.push(format!("{} {label}", r.steps));
        let (err, err_y) = r
            .rows
            .iter()
            .map(|q| ((q.u - ch.ideal(q.y)).abs() / peak, q.y))
            .fold((0.0, f64::NAN), |a, b| if b.0 > a.0 { b } else { a });
        let (u_c, u_wall) = (
            r.rows[r.rows.len() / 2].u,
            r.rows
                .first()
                .map(|q| q.u - ch.ideal(q.y))
                .unwrap_or(f64::NAN),
        );
        s.notes.push(format!(
            "{label}, h = W/{n:.0}: the largest error against the ideal profile is at y = {}; the plug rows move at {} u_p (regularised: {} u_p), the row next to the wall lags the ideal profile by {} u_p.",
            sci(err_y),
            sci(u_c / peak),
            sci(reg_at(0.5) / peak),
            sci(-u_wall / peak)
        ));
        let err_reg = r
            .rows
            .iter()
            .map(|q| (q.u - reg_at(q.y)).abs())
            .fold(0.0, f64::max)
            / peak;
        let w = plug_width(&r.rows, ch.half_width(), ch.yield_stress);
        s.rows.push(Row::bounded(
            format!("{label}, h = W/{n:.0}: max |u - u_ideal| / u_p"),
            err,
            0.03,
            pct,
            // the quick grid (h = W/16) is held to the same bounds (0.5 % and 0.4 h measured)
            true,
            quick,
        ));
        s.rows.push(Row::report(
            format!("{label}, h = W/{n:.0}: max |u - u_regularised| / u_p"),
            pct(err_reg),
        ));
        let mut row = Row::bounded(
            format!(
                "{label}, h = W/{n:.0}: plug width w = {} against 2 y0 = {}: |w - 2 y0|",
                sci(w),
                sci(2.0 * y0)
            ),
            (w - 2.0 * y0).abs(),
            h,
            |v| cells(v, h),
            true,
            quick,
        );
        row.bound = format!("<= h = {}", sci(h));
        s.rows.push(row);
        s.rows.push(Row::report(
            format!("{label}: change of the plug speed over the last 0.1 / u_p (steadiness)"),
            pct((r.centre_end - r.centre_before).abs() / peak),
        ));
        // the projection's rows as markers, the explicit's as a thin line through its rows:
        // the two lie on top of each other
        let mark = if scheme == Scheme::Projection {
            Series::markers
        } else {
            Series::thin
        };
        profile.push(mark(
            format!("pmpm {label}, h = W/{n:.0}"),
            r.rows.iter().map(|q| (q.u / peak, q.y)).collect(),
            color,
        ));
        stress.push(mark(
            format!("pmpm {label}"),
            r.rows
                .iter()
                .map(|q| (q.sqrt_j2 / ch.yield_stress, q.y))
                .collect(),
            color,
        ));
        history.push(Series::line(
            format!("pmpm {label}"),
            r.history.clone(),
            color,
        ));
    }
    let head = channel_section(n, &steps_text.join(", "));
    (s.title, s.setup, s.metric, s.bound) = (head.title, head.setup, head.metric, head.bound);
    s.notes.push(plug_note(&ch));
    s.figures = vec![channel_figure(ctx, profile, stress, history)?];
    Ok(s)
}

/// The exact profiles (ideal and regularised) and stresses the channel's figure draws the
/// particle rows against: (velocity series, stress series).
fn reference_series(ch: &Channel, reg: &[(f64, f64)]) -> (Vec<Series>, Vec<Series>) {
    let peak = ch.peak();
    let profile = vec![
        Series::line(
            "ideal Bingham",
            (0..=200)
                .map(|i| {
                    let y = i as f64 / 200.0;
                    (ch.ideal(y) / peak, y)
                })
                .collect(),
            colors::REF,
        ),
        Series::line(
            format!("regularised, m = {}", ch.exponent),
            reg.iter().map(|&(y, u)| (u / peak, y)).collect(),
            colors::REF2,
        ),
    ];
    let mut stress = vec![Series::line(
        "exact |tau_xy| = G |y - W/2|",
        {
            let wall = ch.drive() * ch.half_width() / ch.yield_stress;
            vec![(wall, 0.0), (0.0, 0.5), (wall, 1.0)]
        },
        colors::REF,
    )];
    stress.push(Series::line(
        "tau_y",
        vec![(1.0, 0.0), (1.0, 1.0)],
        colors::REF2,
    ));
    (profile, stress)
}

/// The channel's figure: velocity profiles, stress profiles and the error's history.
fn channel_figure(
    ctx: &Ctx,
    profile: Vec<Series>,
    stress: Vec<Series>,
    history: Vec<Series>,
) -> Result<String, String> {
    let file = "bingham_poiseuille.png".to_string();
    save(
        &ctx.opts.out.join(&file),
        &[
            Panel {
                title: "Bingham Poiseuille: velocity at t = 0.8".into(),
                x_label: "u / u_p".into(),
                y_label: "y / W".into(),
                series: profile,
                x_range: Some((0.0, 1.1)),
                y_range: Some((0.0, 1.0)),
                legend_left: true,
                ..Default::default()
            },
            Panel {
                title: "sqrt(J2) / tau_y of the particle rows".into(),
                x_label: "sqrt(J2) / tau_y".into(),
                y_label: "y / W".into(),
                series: stress,
                x_range: Some((0.0, 5.5)),
                y_range: Some((0.0, 1.0)),
                ..Default::default()
            },
            Panel {
                title: "max |u - u_ideal| / u_p over the rows".into(),
                x_label: "t".into(),
                y_label: "error / u_p".into(),
                series: history,
                y_range: Some((0.0, 0.05)),
                ..Default::default()
            },
        ],
        3,
        600,
        550,
    )?;
    Ok(file)
}

/// The channel's title, set-up, metric and bound (`validation/prose/bingham_poiseuille.md`) at
/// h = W / `n`; `steps`: the runs' numbers of steps, in words.
fn channel_section(n: f64, steps: &str) -> Section {
    prose::section(
        "bingham_poiseuille",
        &[("steps", &steps), ("n", &format!("{n:.0}"))],
    )
}

/// What the ideal and the regularised plug are, for the notes.
fn plug_note(ch: &Channel) -> String {
    let y0 = ch.plug_half_width();
    prose::note(
        "bingham_poiseuille",
        "plug",
        &[
            ("y0", &y0),
            (
                "creep",
                &sci(1.0 + ch.yield_stress * ch.exponent / ch.viscosity),
            ),
            ("gap", &sci(y0 / ch.exponent)),
        ],
    )
}

/// Every text of the case's prose the code fills (the prose file's test).
#[cfg(test)]
pub(super) fn prose_texts(quick: bool) -> Vec<String> {
    let n = cells_across(quick);
    let mut t = channel_section(n, "1234 projection, 1234 explicit").texts();
    t.push(plug_note(&CASE));
    t
}

/// How far the regularised law's own steady profile is from the ideal Bingham one.
fn regularisation_row(ch: &Channel, reg: &[(f64, f64)]) -> Row {
    let (peak, y0) = (ch.peak(), ch.plug_half_width());
    let reg_gap = reg
        .iter()
        .map(|&(y, u)| (u - ch.ideal(y)).abs())
        .fold(0.0, f64::max)
        / peak;
    Row::report(
        "regularisation alone: max |u_regularised - u_ideal| / u_p (exact steady profiles)",
        format!(
            "{} (closed form y0 / (m u_p) = {})",
            pct(reg_gap),
            pct(y0 / ch.exponent / peak)
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use pmpm::material::Viscoplastic;

    #[test]
    fn the_ideal_profile_is_continuous_and_stops_at_the_walls() {
        let ch = CASE;
        assert_eq!(ch.ideal(0.0), 0.0);
        assert!(ch.ideal(1.0).abs() < 1e-15);
        assert!((ch.peak() - 0.08).abs() < 1e-15);
        // at the plug edge the sheared branch meets the plug speed with zero slope
        let y0 = ch.plug_half_width();
        let edge = 0.5 - y0;
        assert!((ch.ideal(edge - 1e-7) - ch.peak()).abs() < 1e-12);
        // G (r - y0) / mu_p just outside the plug
        let slope = (ch.ideal(edge) - ch.ideal(edge - 1e-3)) / 1e-3;
        assert!((slope - 0.5e-3).abs() < 1e-6, "{slope}");
    }

    #[test]
    fn newton_inverts_the_regularised_law_as_the_material_code_has_it() {
        let ch = CASE;
        let law = Viscoplastic {
            consistency: ch.viscosity,
            flow_index: 1.0,
            yield_stress: ch.yield_stress,
            exponent: ch.exponent,
        };
        for tau in [1e-6, 0.01, 0.0999, 0.1, 0.1001, 0.2, 0.5] {
            let gamma = ch.regularised_shear_rate(tau);
            let back = law.apparent_viscosity(gamma) * gamma;
            assert!((back - tau).abs() < 1e-13, "{tau}: {back}");
        }
    }

    #[test]
    fn the_regularised_centre_speed_exceeds_the_ideal_by_y0_over_m() {
        // the area between the flow curves, tau_y / m, over G (module comment)
        for m in [100.0, 250.0, 1000.0] {
            let ch = Channel {
                exponent: m,
                ..CASE
            };
            let prof = ch.regularised(200);
            let centre = prof[100].1;
            let gap = centre - ch.peak();
            let exact = ch.plug_half_width() / m;
            assert!(
                (gap - exact).abs() < 1e-3 * exact,
                "m = {m}: {gap} vs {exact}"
            );
            // and the gap shrinks to zero at the walls
            assert!(prof[0].1.abs() < 1e-15 && prof[200].1.abs() < 1e-15);
        }
    }

    #[test]
    fn the_plug_edges_are_interpolated_where_sqrt_j2_crosses_tau_y() {
        // |tau| = |y - 0.5| sampled on rows 0.05 apart: crossing of 0.1 at 0.4 and 0.6
        let rows: Vec<RowState> = (0..20)
            .map(|k| {
                let y = 0.025 + 0.05 * k as f64;
                RowState {
                    y,
                    u: 0.0,
                    sqrt_j2: (y - 0.5).abs(),
                }
            })
            .collect();
        assert!((plug_width(&rows, 0.5, 0.1) - 0.2).abs() < 1e-12);
        // everything yielded: no plug
        assert_eq!(plug_width(&rows, 0.5, 0.01), 0.0);
    }
}
