//! The `[[materials]]` section of the deck: each material's model and parameters, their
//! checks, and the step's [`MaterialParams`] built from them (docs/materials.md).

use super::{Law, MaterialParams, Model, Newtonian, ViscoElastic};
use super::{NeoHookean, Viscoplastic, VonMises};
use crate::error::DeckError;
use crate::keys::{short, Check};
use serde::{Deserialize, Serialize};

/// The largest value of a material parameter (Pa, Pa s, kg/m^3, ...): far past any material
/// (the stiffest solids' moduli are about 1e12 Pa, the mantle's viscosity 1e22 Pa s), and
/// low enough that a stress's square stays finite.
pub const MAX_MATERIAL_PARAMETER: f64 = 1e100;

/// `[[materials]]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDeck {
    /// Name bodies refer to.
    pub name: String,
    /// Constitutive model (default `newtonian`).
    #[serde(default)]
    pub model: Model,
    /// Density (kg/m3).
    pub density: f64,
    /// Dynamic viscosity (Pa s), default 0: the Newtonian viscosity, Bingham's plastic
    /// viscosity, a neo-Hookean solid's damping.
    #[serde(default)]
    pub viscosity: f64,
    /// Bulk modulus (Pa) of the equation of state; required by `scheme = "explicit"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bulk_modulus: Option<f64>,
    /// Yield stress tau_y (Pa): `bingham`, `herschel_bulkley`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub yield_stress: Option<f64>,
    /// Papanastasiou exponent m (s): `bingham`, `herschel_bulkley`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub papanastasiou_exponent: Option<f64>,
    /// Consistency K (Pa s^n): `herschel_bulkley`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub consistency: Option<f64>,
    /// Flow index n: `herschel_bulkley`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow_index: Option<f64>,
    /// Shear modulus G (Pa): `neo_hookean_incompressible`, `von_mises`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shear_modulus: Option<f64>,
    /// Undrained shear strength c_u (Pa): `von_mises`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub undrained_shear_strength: Option<f64>,
}

impl MaterialDeck {
    /// The `[[materials]]`: at least one, names apart, each model's keys and no others, each
    /// value in range; the equation of state's bulk modulus where the scheme is `explicit`.
    pub(crate) fn check_all(
        materials: &[MaterialDeck],
        explicit: bool,
        c: &Check,
    ) -> Result<(), DeckError> {
        if materials.is_empty() {
            return Err(c.err("materials", "at least one [[materials]] entry is required"));
        }
        if materials.len() > u16::MAX as usize + 1 {
            // a particle keeps its material's index in a u16
            return Err(c.err(
                "materials",
                format!(
                    "{} entries, too many: pmpm takes at most {}",
                    materials.len(),
                    u16::MAX as usize + 1
                ),
            ));
        }
        for (i, m) in materials.iter().enumerate() {
            let k = format!("materials[{i}]");
            if m.name.trim().is_empty() {
                return Err(c.err(format!("{k}.name"), "must not be empty"));
            }
            if materials[..i].iter().any(|o| o.name == m.name) {
                return Err(c.err(
                    format!("{k}.name"),
                    format!("\"{}\" is defined twice", m.name),
                ));
            }
            c.positive(&format!("{k}.density"), m.density)?;
            c.non_negative(&format!("{k}.viscosity"), m.viscosity)?;
            m.check_model_keys(&k, c)?;
            m.check_magnitudes(&k, c)?;
            match m.bulk_modulus {
                Some(b) => c.positive(&format!("{k}.bulk_modulus"), b)?,
                None if explicit => {
                    return Err(c.err(
                        format!("{k}.bulk_modulus"),
                        "is required by scheme = \"explicit\" (equation of state p = K (1 - J))",
                    ))
                }
                None => {}
            }
        }
        Ok(())
    }

    /// The step's parameters of this validated entry.
    pub fn params(&self) -> MaterialParams {
        let m = self;
        let law = match m.model {
            Model::Newtonian => Law::Newtonian(Newtonian {
                viscosity: m.viscosity,
            }),
            Model::Bingham | Model::HerschelBulkley => Law::Viscoplastic(Viscoplastic {
                consistency: if m.model == Model::Bingham {
                    m.viscosity
                } else {
                    m.consistency.unwrap_or(0.0)
                },
                flow_index: m.flow_index.unwrap_or(1.0),
                yield_stress: m.yield_stress.unwrap_or(0.0),
                exponent: m.papanastasiou_exponent.unwrap_or(0.0),
            }),
            Model::NeoHookeanIncompressible => Law::NeoHookean(ViscoElastic {
                elastic: NeoHookean {
                    shear_modulus: m.shear_modulus.unwrap_or(0.0),
                },
                viscosity: m.viscosity,
            }),
            Model::VonMises => Law::VonMises(VonMises {
                shear_modulus: m.shear_modulus.unwrap_or(0.0),
                strength: m.undrained_shear_strength.unwrap_or(0.0),
            }),
        };
        MaterialParams {
            model: m.model,
            density: m.density,
            bulk_modulus: m.bulk_modulus.unwrap_or(0.0),
            law,
        }
    }

    /// A solid: a material with a shear modulus (its J is its deformation, its waves set the
    /// projection's step).
    pub fn is_solid(&self) -> bool {
        self.shear_modulus.is_some()
    }

    /// The model parameters a material may give, each with its key (the keys some models
    /// require and others refuse).
    fn model_parameters(&self) -> [(&'static str, Option<f64>); 6] {
        [
            ("yield_stress", self.yield_stress),
            ("papanastasiou_exponent", self.papanastasiou_exponent),
            ("consistency", self.consistency),
            ("flow_index", self.flow_index),
            ("shear_modulus", self.shear_modulus),
            ("undrained_shear_strength", self.undrained_shear_strength),
        ]
    }

    /// The model's keys against those given: each given key must be the model's, each required
    /// one given, each value in range.
    fn check_model_keys(&self, k: &str, c: &Check) -> Result<(), DeckError> {
        let model = self.model;
        let own = model.keys();
        let list = || {
            own.iter()
                .map(|(key, required)| {
                    format!("{key}{}", if *required { "" } else { " (optional)" })
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        let viscosity = (
            "viscosity",
            (self.viscosity != 0.0).then_some(self.viscosity),
        );
        let given: Vec<(&str, Option<f64>)> = std::iter::once(viscosity)
            .chain(self.model_parameters())
            .collect();
        for &(key, value) in &given {
            let Some(v) = value else { continue };
            if !own.iter().any(|(o, _)| *o == key) {
                return Err(c.err(
                    format!("{k}.{key}"),
                    format!(
                        "is not a key of model = \"{}\" (its keys: {})",
                        model.name(),
                        list()
                    ),
                ));
            }
            let full = format!("{k}.{key}");
            match key {
                "yield_stress" | "viscosity" => c.non_negative(&full, v)?,
                _ => c.positive(&full, v)?,
            }
        }
        for (key, _) in own.iter().filter(|(_, required)| *required) {
            if given.iter().any(|(g, v)| g == key && v.is_some()) {
                continue;
            }
            let why = if *key == "viscosity" {
                "must be > 0: it is the plastic viscosity of model = \"bingham\"".to_string()
            } else {
                format!(
                    "is required by model = \"{}\" (its keys: {})",
                    model.name(),
                    list()
                )
            };
            let hint = match *key {
                "papanastasiou_exponent" => {
                    "; it sets how rigid the unyielded material is (a creep viscosity of about \
                     yield_stress * m) and so the time step: try m such that yield_stress * m \
                     is 100 to 1000 times the viscosity"
                }
                _ => "",
            };
            return Err(c.err(format!("{k}.{key}"), format!("{why}{hint}")));
        }
        Ok(())
    }

    /// Every parameter is at most [`MAX_MATERIAL_PARAMETER`]: a stress computed from one
    /// past it overflows when squared (a yield test, an energy), and the run would stop on a
    /// NaN blamed on a blow-up.
    fn check_magnitudes(&self, k: &str, c: &Check) -> Result<(), DeckError> {
        let common = [
            ("density", Some(self.density)),
            ("viscosity", Some(self.viscosity)),
            ("bulk_modulus", self.bulk_modulus),
        ];
        for (key, v) in common.into_iter().chain(self.model_parameters()) {
            if let Some(v) = v.filter(|&v| v > MAX_MATERIAL_PARAMETER) {
                return Err(c.err(
                    format!("{k}.{key}"),
                    format!(
                        "{} is beyond what a run can compute with: at most {MAX_MATERIAL_PARAMETER:e} (a stress from it overflows double precision when squared)",
                        short(v)
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The key that sets the largest viscosity of the model ([`crate::material::Constitutive::max_viscosity`]),
    /// for messages.
    pub(crate) fn viscosity_key(&self) -> &'static str {
        match self.model {
            Model::HerschelBulkley => "consistency",
            Model::Bingham
                if self.yield_stress.unwrap_or(0.0)
                    * self.papanastasiou_exponent.unwrap_or(0.0)
                    > self.viscosity =>
            {
                "papanastasiou_exponent"
            }
            _ => "viscosity",
        }
    }

    /// One line for `pmpm check`: name, model, density and the model's parameters.
    pub fn describe(&self) -> String {
        let mut out = format!(
            "\"{}\": {}, density {} kg/m3",
            self.name,
            self.model.name(),
            self.density
        );
        let values = [
            ("viscosity", Some(self.viscosity), "Pa s"),
            ("yield stress", self.yield_stress, "Pa"),
            ("papanastasiou exponent", self.papanastasiou_exponent, "s"),
            ("consistency", self.consistency, "Pa s^n"),
            ("flow index", self.flow_index, ""),
            ("shear modulus", self.shear_modulus, "Pa"),
            (
                "undrained shear strength",
                self.undrained_shear_strength,
                "Pa",
            ),
            ("bulk modulus", self.bulk_modulus, "Pa"),
        ];
        for (name, v, unit) in values {
            let Some(v) = v else { continue };
            let key = name.replace(' ', "_");
            let used = key == "bulk_modulus" || self.model.keys().iter().any(|(k, _)| *k == key);
            if used {
                out += &format!(
                    ", {name} {v:e}{}{unit}",
                    if unit.is_empty() { "" } else { " " }
                );
            }
        }
        out
    }
}
