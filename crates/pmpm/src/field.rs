//! Vector fields of the deck given by numbers or by expressions in x, y, z and t (docs/deck.md,
//! "Fields given by expressions"): initial velocity, body force, wall velocity.
//!
//! Expressions are parsed and evaluated by exmex (a well-kept parser, MIT/Apache); this module
//! only checks the names used, maps `pi` to exmex's `PI`, and turns its errors into a message
//! that quotes the expression.

use crate::grid::Vector;
use exmex::prelude::*;
use serde::{Deserialize, Serialize};

/// One component: a number or an expression.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Component {
    /// A constant.
    Number(f64),
    /// An expression in x, y, z, t.
    Expression(String),
}

/// A vector given component by component.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(transparent)]
pub struct VectorField(pub Vec<Component>);

/// Names an expression may use besides numbers and operators.
const FUNCTIONS: [&str; 22] = [
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp", "ln",
    "log", "log10", "sqrt", "abs", "min", "max", "floor", "ceil", "round", "signum",
];
const VARIABLES: [&str; 4] = ["x", "y", "z", "t"];

impl VectorField {
    /// A constant field.
    pub fn constant_from(v: &[f64]) -> Self {
        Self(v.iter().map(|&c| Component::Number(c)).collect())
    }

    /// Number of components.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether no component is given.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The values, if every component is a number.
    pub fn numbers(&self) -> Option<Vec<f64>> {
        self.0
            .iter()
            .map(|c| match c {
                Component::Number(v) => Some(*v),
                Component::Expression(_) => None,
            })
            .collect()
    }

    /// Parses every expression; the error quotes the one that fails and says why.
    pub fn compile(&self) -> Result<CompiledField, String> {
        let comps = self
            .0
            .iter()
            .enumerate()
            .map(|(k, c)| match c {
                Component::Number(v) => Ok(Compiled::Constant(*v)),
                Component::Expression(text) => {
                    compile_one(text).map_err(|e| format!("[{k}] = \"{text}\": {e}"))
                }
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(CompiledField { comps })
    }
}

#[derive(Debug, Clone)]
enum Compiled {
    Constant(f64),
    Expression {
        ex: Box<FlatEx<f64>>,
        /// For each of exmex's variables (in its order), the index in (x, y, z, t).
        vars: Vec<usize>,
    },
}

fn compile_one(text: &str) -> Result<Compiled, String> {
    // names: every identifier must be a variable, `pi` or a function
    let mut prepared = String::with_capacity(text.len());
    let chars: Vec<char> = text.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_ascii_digit() || (c == '.' && chars.get(i + 1).is_some_and(|c| c.is_ascii_digit()))
        {
            // a number; exmex has no exponent notation, so 1.5e-3 becomes (1.5*10^(-3))
            let start = i;
            while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
                i += 1;
            }
            let mantissa: String = chars[start..i].iter().collect();
            let mut j = i;
            if j < chars.len() && (chars[j] == 'e' || chars[j] == 'E') {
                j += 1;
                let sign_start = j;
                if j < chars.len() && (chars[j] == '+' || chars[j] == '-') {
                    j += 1;
                }
                let digits_start = j;
                while j < chars.len() && chars[j].is_ascii_digit() {
                    j += 1;
                }
                if j > digits_start {
                    let exponent: String = chars[sign_start..j].iter().collect();
                    prepared.push_str(&format!("({mantissa}*10^({exponent}))"));
                    i = j;
                    continue;
                }
            }
            prepared.push_str(&mantissa);
        } else if c.is_ascii_alphabetic() || c == '_' {
            let start = i;
            while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            let name: String = chars[start..i].iter().collect();
            if name == "pi" {
                prepared.push_str("PI");
            } else if VARIABLES.contains(&name.as_str()) || FUNCTIONS.contains(&name.as_str()) {
                prepared.push_str(&name);
            } else {
                return Err(format!(
                    "unknown name `{name}`: the variables are x, y, z, t, the constant pi, and the functions {}",
                    FUNCTIONS.join(", ")
                ));
            }
        } else {
            prepared.push(c);
            i += 1;
        }
    }
    let ex = FlatEx::<f64>::parse(&prepared).map_err(|e| {
        // exmex's messages may end with debug dumps of its operators: keep the sentence
        let msg = e.to_string();
        let cut = msg.find(", Operator {").or_else(|| msg.find(" Operator {"));
        match cut {
            Some(k) => msg[..k].to_string(),
            None => msg,
        }
    })?;
    let vars = ex
        .var_names()
        .iter()
        .map(|v| {
            VARIABLES
                .iter()
                .position(|n| n == v)
                .expect("names checked above")
        })
        .collect();
    let compiled = Compiled::Expression {
        ex: Box::new(ex),
        vars,
    };
    // an expression must give a number at the origin at t = 0 (catches "sqrt(-1)")
    let probe = eval_one(&compiled, &[0.0; 4]);
    if probe.is_none() {
        return Err("cannot be evaluated".into());
    }
    Ok(compiled)
}

fn eval_one(c: &Compiled, xyzt: &[f64; 4]) -> Option<f64> {
    match c {
        Compiled::Constant(v) => Some(*v),
        Compiled::Expression { ex, vars } => {
            let mut args = [0.0; 4];
            for (k, &v) in vars.iter().enumerate() {
                args[k] = xyzt[v];
            }
            ex.eval(&args[..vars.len()]).ok()
        }
    }
}

/// A field ready to evaluate.
#[derive(Debug, Clone)]
pub struct CompiledField {
    comps: Vec<Compiled>,
}

impl CompiledField {
    /// Whether no component depends on x, y, z or t.
    pub fn is_constant(&self) -> bool {
        self.comps.iter().all(|c| match c {
            Compiled::Constant(_) => true,
            Compiled::Expression { vars, .. } => vars.is_empty(),
        })
    }

    /// Whether a component names x, y or z (as exmex recorded its variables when it parsed
    /// the expression: `0*x` names x, a sampled value would not show it).
    pub fn uses_position(&self) -> bool {
        self.comps.iter().any(|c| match c {
            Compiled::Constant(_) => false,
            Compiled::Expression { vars, .. } => vars.iter().any(|&v| v < 3),
        })
    }

    /// The value at position `x` and time `t` (a component that fails to evaluate is NaN,
    /// which the blow-up guard reports).
    pub fn eval<const D: usize>(&self, x: &Vector<D>, t: f64) -> Vector<D> {
        let mut xyzt = [0.0; 4];
        for d in 0..D.min(3) {
            xyzt[d] = x[d];
        }
        xyzt[3] = t;
        Vector::<D>::from_fn(|d, _| eval_one(&self.comps[d], &xyzt).unwrap_or(f64::NAN))
    }

    /// Number of components.
    pub fn len(&self) -> usize {
        self.comps.len()
    }

    /// Whether it has no component.
    pub fn is_empty(&self) -> bool {
        self.comps.is_empty()
    }

    /// The value at the origin at time `t` as a 3-vector (components past the field's zero),
    /// for fields of t only: a rigid body's velocity and angular velocity.
    pub fn eval_t(&self, t: f64) -> nalgebra::Vector3<f64> {
        let xyzt = [0.0, 0.0, 0.0, t];
        nalgebra::Vector3::from_fn(|d, _| {
            self.comps
                .get(d)
                .map_or(0.0, |c| eval_one(c, &xyzt).unwrap_or(f64::NAN))
        })
    }

    /// The value at a point given as a slice of its components (as many as the field's),
    /// for the deck's checks, which know the dimension only at run time.
    pub fn eval_at(&self, x: &[f64], t: f64) -> Vec<f64> {
        let mut xyzt = [0.0; 4];
        for (d, c) in x.iter().take(3).enumerate() {
            xyzt[d] = *c;
        }
        xyzt[3] = t;
        self.comps
            .iter()
            .map(|c| eval_one(c, &xyzt).unwrap_or(f64::NAN))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(parts: &[&str]) -> VectorField {
        VectorField(
            parts
                .iter()
                .map(|p| match p.parse::<f64>() {
                    Ok(v) => Component::Number(v),
                    Err(_) => Component::Expression(p.to_string()),
                })
                .collect(),
        )
    }

    #[test]
    fn taylor_green_velocity_evaluates() {
        let f = field(&["-sin(pi*x)*cos(pi*y)", "cos(pi*x)*sin(pi*y)"])
            .compile()
            .unwrap();
        let v = f.eval(&Vector::<2>::new(0.5, 0.0), 0.0);
        assert!((v[0] + 1.0).abs() < 1e-15 && v[1].abs() < 1e-15);
        assert!(!f.is_constant());
    }

    #[test]
    fn the_variables_an_expression_names_are_known() {
        let t_only = field(&["2.5", "sin(t)*exp(-t)"]).compile().unwrap();
        assert!(!t_only.uses_position());
        for space in ["sin(pi*y)", "0*x + t", "z"] {
            let f = field(&["t", space]).compile().unwrap();
            assert!(f.uses_position(), "{space}");
        }
    }

    #[test]
    fn numbers_time_and_functions() {
        let f = field(&["2.5", "1e-3*exp(-t)+max(x, 0)"]).compile().unwrap();
        let v = f.eval(&Vector::<2>::new(-1.0, 0.0), 0.0);
        assert_eq!(v[0], 2.5);
        assert!((v[1] - 1e-3).abs() < 1e-18);
        assert!(field(&["1", "sqrt(4)"]).compile().unwrap().is_constant());
    }

    #[test]
    fn bad_expressions_are_quoted_with_the_reason() {
        let e = field(&["0", "sin(q*x)"]).compile().unwrap_err();
        assert!(e.starts_with("[1] = \"sin(q*x)\": unknown name `q`"), "{e}");
        let e = field(&["1 +* x", "0"]).compile().unwrap_err();
        assert!(e.starts_with("[0] = \"1 +* x\": "), "{e}");
        assert!(!e.contains("Operator {"), "{e}");
    }
}
