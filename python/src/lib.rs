//! The native module `pmpm._pmpm` behind the Python package `pmpm`: a deck (a file or a
//! dict) made into a simulation that Python steps, runs to a time, and reads as NumPy arrays;
//! and `run`, which writes a run directory as `pmpm run` does.
//!
//! Every field is a copy, in particle id order: the solver sorts its particles in memory and
//! inflows and outflows add and remove them, so a view into its arrays would change meaning
//! or dangle at the next step. A copy costs one pass over the field, far less than a step.
//! The steps run with the GIL released.

use numpy::ndarray::{Array1, Array2, Array3, ArrayD, IxDyn};
use numpy::IntoPyArray;
use pmpm::driver::{Clock, Driver};
use pmpm::grid_fields::{self, NodeFields};
use pmpm::run::{RunOptions, Silent};
use pmpm::scheme::Simulation as Sim;
use pmpm::{build, Deck, Error};
use pyo3::exceptions::{PyKeyError, PyKeyboardInterrupt, PyOSError, PyRuntimeError};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

pyo3::create_exception!(
    _pmpm,
    DeckError,
    PyValueError,
    "The deck is wrong; the message names the key (exit status 2 from the command line)."
);
pyo3::create_exception!(
    _pmpm,
    SolverError,
    PyRuntimeError,
    "The run blew up: a NaN, or a particle left the grid (exit status 3 from the command line)."
);

/// The Python exception for a solver error, of the class its exit status stands for.
fn py_err(e: Error) -> PyErr {
    py_err_as(e, |m| m)
}

/// [`py_err`] with its message passed through `edit`.
fn py_err_as(e: Error, edit: impl FnOnce(String) -> String) -> PyErr {
    let message = edit(for_python(&pmpm::limits::shorten_numbers(&e.to_string())));
    match e {
        Error::Deck(_) | Error::Unsupported { .. } | Error::Usage(_) => DeckError::new_err(message),
        Error::Io { .. } => PyOSError::new_err(message),
        Error::BlowUp(_) => SolverError::new_err(message),
        Error::Interrupted(_) => PyKeyboardInterrupt::new_err(message),
    }
}

/// A solver message with the command line's options named as the Python entry points take
/// them (the limits' messages name `--allow-large` and `--threads`).
fn for_python(message: &str) -> String {
    message
        .replace("pass --allow-large", "pass allow_large=True")
        .replace("fewer --threads", "fewer threads")
}

/// The particle fields `Simulation.particle_field` reads.
const PARTICLE_FIELDS: [&str; 13] = [
    "id",
    "position",
    "velocity",
    "mass",
    "volume0",
    "volume",
    "jacobian",
    "pressure",
    "stress",
    "strain_rate",
    "shear_rate",
    "material",
    "yielded",
];

/// The node fields `Simulation.grid_field` reads (those of `formats = ["grid"]`).
const GRID_FIELDS: [&str; 9] = [
    "mass",
    "velocity",
    "pressure",
    "volume_fraction",
    "density",
    "strain_rate",
    "shear_rate",
    "stress",
    "yielded",
];

/// The deepest a deck given as a dict may nest (tables, arrays): a deck has a few levels; a
/// dict 20,000 deep, or one that holds itself, used to overflow the stack of the conversion
/// and crash the interpreter.
const MAX_DEPTH: usize = 64;

/// A dict's deck turned into TOML: `file` names it in messages (`<dict>`).
struct ToToml<'a> {
    file: &'a str,
}

impl ToToml<'_> {
    /// `file: key: message`, the form of the deck's own errors (`key` empty: the deck).
    fn at(&self, key: &str, message: impl std::fmt::Display) -> String {
        let key = if key.is_empty() { "the deck" } else { key };
        format!("{}: {key}: {message}", self.file)
    }

    /// A TOML value of a Python object nested `depth` deep; `key` names it in errors.
    fn value(&self, obj: &Bound<'_, PyAny>, key: &str, depth: usize) -> PyResult<toml::Value> {
        use toml::Value;
        if depth > MAX_DEPTH {
            return Err(DeckError::new_err(self.at(
                key,
                format!("nested more than {MAX_DEPTH} deep (a deck has a few levels of tables and arrays; does a dict or list hold itself?)"),
            )));
        }
        if obj.is_instance_of::<PyBool>() {
            return Ok(Value::Boolean(obj.extract()?));
        }
        if obj.is_instance_of::<PyInt>() {
            return obj.extract().map(Value::Integer).map_err(|_| {
                DeckError::new_err(self.at(key, format!("integer {} out of range (a deck's integers are 64-bit: -2**63 to 2**63 - 1)", int_text(obj))))
            });
        }
        if obj.is_instance_of::<PyFloat>() {
            return Ok(Value::Float(obj.extract()?));
        }
        if obj.is_instance_of::<PyString>() {
            return obj.extract().map(Value::String).map_err(|e| {
                DeckError::new_err(
                    self.at(key, format!("the string is not valid Unicode text: {e}")),
                )
            });
        }
        if let Ok(dict) = obj.cast::<PyDict>() {
            let mut table = toml::Table::new();
            for (k, v) in dict.iter() {
                let name: String = k.extract().map_err(|_| {
                    PyTypeError::new_err(self.at(key, format!("a key is not a string: {k}")))
                })?;
                let path = if key.is_empty() {
                    name.clone()
                } else {
                    format!("{key}.{name}")
                };
                if !v.is_none() {
                    table.insert(name, self.value(&v, &path, depth + 1)?);
                }
            }
            return Ok(Value::Table(table));
        }
        if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
            let items = obj
                .try_iter()?
                .enumerate()
                .map(|(i, v)| self.value(&v?, &format!("{key}[{i}]"), depth + 1))
                .collect::<PyResult<Vec<_>>>()?;
            return Ok(Value::Array(items));
        }
        self.other(obj, key, depth)
    }

    /// A value of another type: a NumPy scalar or array (as the Python number or nested list
    /// its `tolist()` gives), an integer type (`__index__`) or a float type (`__float__`).
    fn other(&self, obj: &Bound<'_, PyAny>, key: &str, depth: usize) -> PyResult<toml::Value> {
        let type_name = obj.get_type().name()?.to_string();
        let refused = |why: String| {
            PyTypeError::new_err(self.at(
                key,
                format!("a {type_name} cannot be written in a deck{why} (use a bool, int, float, str, list or dict, or a NumPy number or array)"),
            ))
        };
        if obj.hasattr("tolist")? {
            let plain = obj
                .call_method0("tolist")
                .map_err(|e| refused(format!(": its tolist() failed: {e}")))?;
            if plain.get_type().is(obj.get_type()) {
                return Err(refused(String::new()));
            }
            return self.value(&plain, key, depth + 1);
        }
        if obj.hasattr("__index__")? {
            let int = obj
                .call_method0("__index__")
                .map_err(|e| refused(format!(": {e}")))?;
            return self.value(&int, key, depth + 1);
        }
        match obj.extract::<f64>() {
            Ok(x) => Ok(toml::Value::Float(x)),
            Err(_) => Err(refused(String::new())),
        }
    }
}

/// An integer for a message: its digits, or its size where they are many (Python refuses
/// to print more than 4300).
fn int_text(obj: &Bound<'_, PyAny>) -> String {
    match obj.str() {
        Ok(s) if s.len().is_ok_and(|n| n <= 40) => s.to_string(),
        _ => match obj.call_method0("bit_length") {
            Ok(bits) => format!("of {bits} bits"),
            Err(_) => "too large".to_string(),
        },
    }
}

/// A Python object of a TOML value.
fn to_py<'py>(py: Python<'py>, v: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    use toml::Value;
    Ok(match v {
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Integer(i) => i.into_pyobject(py)?.into_any(),
        Value::Float(x) => x.into_pyobject(py)?.into_any(),
        Value::Boolean(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Datetime(d) => d.to_string().into_pyobject(py)?.into_any(),
        Value::Array(a) => {
            let items = a
                .iter()
                .map(|v| to_py(py, v))
                .collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, items)?.into_any()
        }
        Value::Table(t) => {
            let dict = PyDict::new(py);
            for (k, v) in t {
                dict.set_item(k, to_py(py, v)?)?;
            }
            dict.into_any()
        }
    })
}

/// A validated deck from a file path or a dict, and the name its messages use. A dict's
/// relative file names (meshes) are read from `base_dir`, by default the working directory.
fn load_deck(deck: &Bound<'_, PyAny>, base_dir: Option<PathBuf>) -> PyResult<(Deck, String)> {
    if let Ok(dict) = deck.cast::<PyDict>() {
        let base = base_dir.unwrap_or_default();
        let file = base.join("<dict>").display().to_string();
        let value = ToToml { file: &file }.value(dict.as_any(), "", 0)?;
        let text = toml::to_string(&value).map_err(|e| {
            PyValueError::new_err(format!("{file}: the deck cannot be written as TOML: {e}"))
        })?;
        let mut deck = Deck::parse(&text, &file).map_err(|e| py_err(e.into()))?;
        deck.validate(&file).map_err(|e| py_err(e.into()))?;
        return Ok((deck, file));
    }
    let path: PathBuf = deck.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "deck: give a file path or a dict, not a {}",
            deck.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    })?;
    let loaded = Deck::load(&path).map_err(|e| py_err(e.into()))?;
    Ok((loaded, path.display().to_string()))
}

/// The simulation of either dimension.
enum Inner {
    Two(Box<Sim<2>>),
    Three(Box<Sim<3>>),
}

/// Runs `$body` with `$s` bound to the simulation, whatever its dimension.
macro_rules! with_sim {
    ($inner:expr, $s:ident => $body:expr) => {
        match $inner {
            Inner::Two($s) => $body,
            Inner::Three($s) => $body,
        }
    };
}

/// A simulation built from a deck, stepped from Python.
///
/// `Simulation(deck, base_dir=None, threads=None)`: `deck` is a deck file's path, or a dict
/// of the same keys (as `pmpm.read_deck` returns); `base_dir` is where a dict's relative
/// file names (meshes) are read from; `threads` is the number of worker threads (all cores
/// by default; results are bitwise repeatable for a given number). The deck is checked as `pmpm check` checks it: a wrong key raises
/// `pmpm.DeckError` naming it. Nothing is written to disk; `pmpm.run` writes a run directory.
#[pyclass(module = "pmpm._pmpm")]
struct Simulation {
    inner: Inner,
    deck: Deck,
    file: String,
    clock: Clock,
    /// Time of the next frame: steps land on frame times as in `pmpm run`.
    next_frame: f64,
    /// The workers of the steps: results are bitwise repeatable for a given count.
    pool: rayon::ThreadPool,
    /// `run(until=...)` may go past the limits on steps (as `allow_large=True` asked).
    allow_large: bool,
}

impl Simulation {
    /// Steps to `until` (or one step when `until` is None) with the deck's step policy;
    /// returns the steps taken. The steps run on the simulation's worker pool with the GIL
    /// released; Ctrl-C (any signal whose handler raises) stops them after the step in
    /// progress and raises, the simulation whole and able to go on.
    fn advance(&mut self, py: Python<'_>, until: Option<f64>) -> PyResult<u64> {
        let clock = Clock {
            end: until.unwrap_or(f64::INFINITY),
            ..self.clock
        };
        let mut driver = Driver::resume(clock, self.next_frame);
        let end = self.deck.simulation.end_time;
        let toward = until.filter(|u| (u - end).abs() > clock.eps());
        let (inner, pool) = (&mut self.inner, &self.pool);
        // The loop runs on a worker of the pool, as `pmpm run` does: the many short parallel
        // loops of a step then start without waking a sleeping thread from outside the pool
        // each time (twice the speed on 2 cores).
        let (taken, signal) = interruptible(py, pool, |stop| -> Result<u64, Error> {
            let mut taken = 0;
            loop {
                if until.is_some() && with_sim!(&*inner, s => driver.finished(s.as_ref())) {
                    return Ok(taken);
                }
                with_sim!(&mut *inner, s => step_toward(&mut driver, s.as_mut(), toward))?;
                taken += 1;
                if until.is_none() || stop.load(Ordering::SeqCst) {
                    return Ok(taken);
                }
            }
        });
        self.next_frame = driver.next_frame;
        let taken = taken.map_err(py_err)?;
        match signal {
            Some(e) => Err(e),
            None => Ok(taken),
        }
    }
}

/// How often the Python thread looks for a signal while the workers step.
const SIGNAL_POLL: Duration = Duration::from_millis(20);

/// Runs `work` on a worker of `pool` while this thread, the interpreter's, releases the GIL
/// and runs Python's signal handlers every [`SIGNAL_POLL`]: Python runs them only on its main
/// thread, never on a worker, so a check there let Ctrl-C go unseen. When a handler raises
/// (KeyboardInterrupt), `work`'s stop flag is set, and its exception is returned beside
/// `work`'s result once `work` has stopped at a step.
fn interruptible<T: Send>(
    py: Python<'_>,
    pool: &rayon::ThreadPool,
    work: impl FnOnce(&Arc<AtomicBool>) -> T + Send,
) -> (T, Option<PyErr>) {
    /// Marks the work done, even when it panics (the scope then raises the panic).
    struct Done<'a>(&'a AtomicBool, std::thread::Thread);
    impl Drop for Done<'_> {
        fn drop(&mut self) {
            self.0.store(true, Ordering::SeqCst);
            self.1.unpark();
        }
    }
    let stop = Arc::new(AtomicBool::new(false));
    let done = AtomicBool::new(false);
    let mut out = None;
    let mut signal = None;
    pool.in_place_scope(|scope| {
        let caller = std::thread::current();
        scope.spawn(|_| {
            let _done = Done(&done, caller);
            out = Some(work(&stop));
        });
        while !done.load(Ordering::SeqCst) {
            py.detach(|| std::thread::park_timeout(SIGNAL_POLL));
            if signal.is_none() {
                if let Err(e) = py.check_signals() {
                    stop.store(true, Ordering::SeqCst);
                    signal = Some(e);
                }
            }
        }
    });
    (out.expect("the work ran to its end"), signal)
}

/// One step of the driver's size, except on the way to a time `until` other than the deck's
/// end (None: to the clock's end, as `pmpm run` steps): when less than two steps are left, they share the time left equally. Cut to land on
/// `until`, the last step could be a sliver, and a projection step that short turns the
/// divergence left over into a pressure spike (the driver's `land_on_frames` avoids the same
/// for frames). Stepping the 2D dam break to each 0.01 s with slivers: 515 steps, the
/// particles' volume off by 0.16 % at worst; `pmpm run`: 499 steps, 0.03 %.
fn step_toward<const D: usize>(
    driver: &mut Driver,
    sim: &mut Sim<D>,
    until: Option<f64>,
) -> Result<(), Error> {
    let dt = match until {
        Some(until) => {
            let natural = Clock {
                end: f64::INFINITY,
                ..driver.clock
            }
            .next_dt(sim, driver.next_frame)?;
            let left = until - sim.time;
            if left < 2.0 * natural {
                // a step a hair short of `natural` (round-off in the time) counts as one
                left / (left / natural - 1e-9).ceil().max(1.0)
            } else {
                natural
            }
        }
        // to the deck's end: the steps `pmpm run` takes
        None => driver.clock.next_dt(sim, driver.next_frame)?,
    };
    driver.step_by(sim, dt).map(|_| ())
}

/// A pool of `threads` workers (all cores by default), as `--threads` makes, and within its
/// limit: at most 8 a core and at least 64 (starting a million threads took minutes).
fn pool(threads: Option<usize>) -> PyResult<rayon::ThreadPool> {
    if threads == Some(0) {
        return Err(PyValueError::new_err("threads: must be at least 1"));
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let most = (8 * cores).max(64);
    if let Some(n) = threads.filter(|&n| n > most) {
        return Err(PyValueError::new_err(format!(
            "threads: {n}: at most {most} on this machine ({cores} cores; up to 8 threads a \
             core, at least 64, so that a run made elsewhere with more threads can be repeated \
             bit for bit)"
        )));
    }
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        builder = builder.num_threads(n);
    }
    builder
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start the worker threads: {e}")))
}

/// Refuses, as `pmpm run` does without `--allow-large`, a deck that needs more memory than
/// the machine has or its address-space limit allows, or more than 1e9 steps to its end
/// time, before anything is allocated; run on `pool` to count its threads' address space.
fn check_limits(
    pool: &rayon::ThreadPool,
    deck: &Deck,
    file: &str,
    allow_large: bool,
) -> PyResult<()> {
    pool.install(|| pmpm::limits::refuse_beyond_limits(deck, file, allow_large))
        .map_err(py_err)
}

/// `(n, D)` of a D-vector per particle.
fn rows<const D: usize>(n: usize, f: impl Fn(usize, usize) -> f64) -> Array2<f64> {
    Array2::from_shape_fn((n, D), |(i, d)| f(i, d))
}

/// `(n, D, D)` of a row-by-row 3 x 3 tensor per particle.
fn tensors<const D: usize>(at: &[usize], f: impl Fn(usize) -> [f64; 9]) -> Array3<f64> {
    let all: Vec<[f64; 9]> = at.iter().map(|&p| f(p)).collect();
    Array3::from_shape_fn((at.len(), D, D), |(i, r, c)| all[i][3 * r + c])
}

/// A particle field of `sim`, in id order.
fn particle_field<'py, const D: usize>(
    py: Python<'py>,
    sim: &Sim<D>,
    name: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let ps = &sim.particles;
    let at = ps.places();
    let n = at.len();
    let scalar = |f: &dyn Fn(usize) -> f64| {
        at.iter()
            .map(|&p| f(p))
            .collect::<Array1<f64>>()
            .into_pyarray(py)
            .into_any()
    };
    Ok(match name {
        "id" => at
            .iter()
            .map(|&p| ps.id[p])
            .collect::<Array1<u32>>()
            .into_pyarray(py)
            .into_any(),
        "material" => at
            .iter()
            .map(|&p| ps.material[p])
            .collect::<Array1<u16>>()
            .into_pyarray(py)
            .into_any(),
        "position" => rows::<D>(n, |i, d| ps.x[at[i]][d])
            .into_pyarray(py)
            .into_any(),
        "velocity" => rows::<D>(n, |i, d| ps.v[at[i]][d])
            .into_pyarray(py)
            .into_any(),
        "mass" => scalar(&|p| ps.mass[p]),
        "volume0" => scalar(&|p| ps.volume0[p]),
        "volume" => scalar(&|p| ps.volume(p)),
        "jacobian" => scalar(&|p| ps.jacobian[p]),
        "pressure" => scalar(&|p| ps.pressure[p]),
        "shear_rate" => scalar(&|p| grid_fields::particle_shear_rate(ps, p)),
        "yielded" => scalar(&|p| grid_fields::particle_yielded(sim, p)),
        "stress" => tensors::<D>(&at, |p| grid_fields::particle_stress(sim, p))
            .into_pyarray(py)
            .into_any(),
        "strain_rate" => tensors::<D>(&at, |p| grid_fields::particle_strain_rate(ps, p))
            .into_pyarray(py)
            .into_any(),
        _ => {
            return Err(PyKeyError::new_err(format!(
                "no particle field {name:?}; the fields are {}",
                PARTICLE_FIELDS.join(", ")
            )))
        }
    })
}

/// A node field, indexed [i, j(, k)(, component...)] with i along x: the node at
/// origin + (i, j, k) h.
fn grid_field<'py>(
    py: Python<'py>,
    f: &NodeFields,
    dim: usize,
    name: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let nodes = &f.nodes[..dim];
    // node (i, j, k) of C order, as the flat x-fastest index NodeFields uses
    let count: usize = nodes.iter().product();
    let flat = |c: usize| -> usize {
        let (mut rest, mut k, mut stride) = (c, 0, 1);
        let mut idx = [0usize; 3];
        for d in (0..dim).rev() {
            idx[d] = rest % nodes[d];
            rest /= nodes[d];
        }
        for d in 0..dim {
            k += idx[d] * stride;
            stride *= nodes[d];
        }
        k
    };
    let shape = |extra: &[usize]| IxDyn(&[nodes, extra].concat());
    let scalar = |v: &[f64]| {
        let data: Vec<f64> = (0..count).map(|c| v[flat(c)]).collect();
        ArrayD::from_shape_vec(shape(&[]), data).expect("one value a node")
    };
    let vector = |v: &[[f64; 3]]| {
        let data: Vec<f64> = (0..count)
            .flat_map(|c| v[flat(c)][..dim].to_vec())
            .collect();
        ArrayD::from_shape_vec(shape(&[dim]), data).expect("D values a node")
    };
    let tensor = |v: &[[f64; 9]]| {
        let data: Vec<f64> = (0..count)
            .flat_map(|c| {
                let t = v[flat(c)];
                (0..dim * dim).map(move |rc| t[3 * (rc / dim) + rc % dim])
            })
            .collect();
        ArrayD::from_shape_vec(shape(&[dim, dim]), data).expect("D x D values a node")
    };
    let array = match name {
        "mass" => scalar(&f.mass),
        "pressure" => scalar(&f.pressure),
        "volume_fraction" => scalar(&f.volume_fraction),
        "density" => scalar(&f.density),
        "shear_rate" => scalar(&f.shear_rate),
        "yielded" => match &f.yielded {
            Some(y) => scalar(y),
            None => scalar(&vec![0.0; count]),
        },
        "velocity" => vector(&f.velocity),
        "strain_rate" => tensor(&f.strain_rate),
        "stress" => tensor(&f.stress),
        _ => {
            return Err(PyKeyError::new_err(format!(
                "no grid field {name:?}; the fields are {}",
                GRID_FIELDS.join(", ")
            )))
        }
    };
    Ok(array.into_pyarray(py).into_any())
}

#[pymethods]
impl Simulation {
    #[new]
    #[pyo3(signature = (deck, *, base_dir = None, threads = None, allow_large = false))]
    fn new(
        deck: &Bound<'_, PyAny>,
        base_dir: Option<PathBuf>,
        threads: Option<usize>,
        allow_large: bool,
    ) -> PyResult<Self> {
        let pool = pool(threads)?;
        let (deck, file) = load_deck(deck, base_dir)?;
        check_limits(&pool, &deck, &file, allow_large)?;
        let build_err = |e: Error| py_err(e.with_file(&file));
        let inner = match deck.simulation.dimension {
            2 => Inner::Two(Box::new(Sim::<2>::new(&deck).map_err(build_err)?)),
            _ => Inner::Three(Box::new(Sim::<3>::new(&deck).map_err(build_err)?)),
        };
        let clock = build::clock(&deck);
        Ok(Self {
            inner,
            next_frame: Driver::new(clock).next_frame,
            deck,
            file,
            clock,
            pool,
            allow_large,
        })
    }

    /// Simulated time (s).
    #[getter]
    fn time(&self) -> f64 {
        with_sim!(&self.inner, s => s.time)
    }

    /// Steps taken.
    #[getter]
    fn steps(&self) -> u64 {
        with_sim!(&self.inner, s => s.steps)
    }

    /// 2 or 3.
    #[getter]
    fn dimension(&self) -> usize {
        self.deck.simulation.dimension
    }

    /// The deck's end time (s): where `run()` stops by default.
    #[getter]
    fn end_time(&self) -> f64 {
        self.deck.simulation.end_time
    }

    /// Number of particles now.
    #[getter]
    fn particle_count(&self) -> usize {
        with_sim!(&self.inner, s => s.particles.len())
    }

    /// The grid's cell size h (m).
    #[getter]
    fn cell_size(&self) -> f64 {
        with_sim!(&self.inner, s => s.grid.geo.h)
    }

    /// Node positions along each axis (m): a tuple of D arrays, the axes of `grid_field`.
    #[getter]
    fn grid_coordinates<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let (origin, h, cells): (Vec<f64>, f64, Vec<usize>) = with_sim!(&self.inner, s => {
            let g = &s.grid.geo;
            (g.origin.as_slice().to_vec(), g.h, g.cells.to_vec())
        });
        let axes = (0..origin.len()).map(|d| {
            (0..=cells[d])
                .map(|i| origin[d] + i as f64 * h)
                .collect::<Array1<f64>>()
                .into_pyarray(py)
        });
        PyTuple::new(py, axes)
    }

    /// The checked deck, every default filled in, as a dict.
    #[getter]
    fn deck<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let value = toml::Value::try_from(&self.deck)
            .map_err(|e| PyRuntimeError::new_err(format!("the deck as TOML: {e}")))?;
        to_py(py, &value)
    }

    /// Mass entered through inflows minus mass left through outflows, relative to what
    /// the run held and took in: (m0 + m_in - m_out - m(t)) / (m0 + m_in), round-off.
    fn mass_balance(&self) -> f64 {
        with_sim!(&self.inner, s => s.ledger.balance(&s.particles))
    }

    /// Takes one step of the deck's size (fixed `dt`, or the stable step at `cfl`, shortened
    /// to land on frame times); returns the step's size (s). It steps past `end_time` too.
    fn step(&mut self, py: Python<'_>) -> PyResult<f64> {
        let t0 = self.time();
        self.advance(py, None)?;
        Ok(self.time() - t0)
    }

    /// Steps to `until` (s; the deck's `end_time` by default), the last step shortened to
    /// land on it; returns the number of steps taken. Raises `pmpm.SolverError` if the run
    /// blows up, with the state of the step before.
    #[pyo3(signature = (until = None))]
    fn run(&mut self, py: Python<'_>, until: Option<f64>) -> PyResult<u64> {
        let until = until.unwrap_or(self.deck.simulation.end_time);
        if !until.is_finite() {
            return Err(PyValueError::new_err(format!(
                "until: must be a finite time, got {until}"
            )));
        }
        if until > self.deck.simulation.end_time && !self.allow_large {
            // the steps to `until`, as the deck's end time is checked when it is built
            let mut deck = self.deck.clone();
            deck.simulation.end_time = until;
            let steps = pmpm::limits::estimate(&deck).steps;
            if steps > pmpm::limits::MAX_STEPS {
                return Err(PyValueError::new_err(format!(
                    "until: {}: the run needs about {} steps to get there, more than {:.0e}; \
                     Simulation(..., allow_large=True) runs it anyway",
                    pmpm::limits::short(until),
                    pmpm::limits::short(steps),
                    pmpm::limits::MAX_STEPS
                )));
            }
        }
        self.advance(py, Some(until))
    }

    /// A particle field as a new NumPy array, one row per particle in id order:
    /// `id` (uint32), `position`, `velocity` (n, D), `mass`, `volume0`, `volume` (J V0),
    /// `jacobian`, `pressure` (positive in compression), `shear_rate`, `yielded` (n),
    /// `stress` (Cauchy, -p I + tau), `strain_rate` (n, D, D), `material` (uint16, the
    /// index into the deck's materials).
    fn particle_field<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        with_sim!(&self.inner, s => particle_field(py, s.as_ref(), name))
    }

    /// A field on the grid's nodes as a new NumPy array indexed [i, j(, k)] with i along x
    /// (see `grid_coordinates`), the particles spread with linear hat weights as for
    /// `formats = ["grid"]`: `mass`, `pressure`, `volume_fraction`, `density`,
    /// `shear_rate`, `yielded` (scalars), `velocity` (..., D), `stress`, `strain_rate`
    /// (..., D, D).
    fn grid_field<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        let fields = with_sim!(&self.inner, s => NodeFields::of(s.as_ref()));
        grid_field(py, &fields, self.dimension(), name)
    }

    /// The names `particle_field` takes.
    #[classattr]
    fn particle_fields() -> Vec<&'static str> {
        PARTICLE_FIELDS.to_vec()
    }

    /// The names `grid_field` takes.
    #[classattr]
    fn grid_fields() -> Vec<&'static str> {
        GRID_FIELDS.to_vec()
    }

    fn __repr__(&self) -> String {
        format!(
            "Simulation({:?}, dimension={}, time={}, steps={}, particles={})",
            self.file,
            self.dimension(),
            self.time(),
            self.steps(),
            self.particle_count()
        )
    }
}

/// Runs a deck to its end time into a run directory, as `pmpm run` does: frames, series.csv,
/// probes, gauges, checkpoints and run.toml. `output` is the directory (the deck's
/// `output.directory` by default); `force` writes over an earlier run there; `threads` as
/// for `Simulation`; `allow_large` runs a deck past the limits on memory and steps; `resume`
/// goes on from a checkpoint (`OUTDIR/checkpoint.bin`) as `pmpm run --resume` does. Ctrl-C
/// finishes the step, writes a frame and a checkpoint and raises `KeyboardInterrupt`.
/// Returns the run's summary as a dict: steps, frames, particles, time, wall_seconds.
#[pyfunction]
#[pyo3(signature = (deck, output = None, *, force = false, base_dir = None, threads = None, allow_large = false, resume = None))]
#[allow(clippy::too_many_arguments)] // Python's keyword arguments
fn run<'py>(
    py: Python<'py>,
    deck: &Bound<'py, PyAny>,
    output: Option<PathBuf>,
    force: bool,
    base_dir: Option<PathBuf>,
    threads: Option<usize>,
    allow_large: bool,
    resume: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let workers = pool(threads)?;
    let (deck, file) = load_deck(deck, base_dir)?;
    check_limits(&workers, &deck, &file, allow_large)?;
    let dir = match output {
        Some(dir) => dir,
        None if !deck.output.directory.is_empty() => PathBuf::from(&deck.output.directory),
        None => {
            return Err(DeckError::new_err(format!(
            "{file}: output.directory: a deck given as a dict needs it, or run(deck, output=...)"
        )))
        }
    };
    let (summary, signal) = interruptible(py, &workers, |stop| {
        let opts = RunOptions {
            force,
            resume,
            interrupt: Some(Arc::clone(stop)),
            ..RunOptions::default()
        };
        pmpm::run::run(&deck, &file, Path::new(&dir), &opts, &mut Silent)
    });
    let run_err = |e| py_err_as(e, |m| python_resume(m, &file, &dir));
    let summary = match (summary, signal) {
        // stopped at a step, its frame and checkpoint written: the run's message says so
        (Err(e @ Error::Interrupted(_)), Some(signal))
            if signal.is_instance_of::<PyKeyboardInterrupt>(py) =>
        {
            return Err(run_err(e))
        }
        (_, Some(signal)) => return Err(signal),
        (summary, None) => summary.map_err(run_err)?,
    };
    let out = PyDict::new(py);
    out.set_item("steps", summary.steps)?;
    out.set_item("frames", summary.frames)?;
    out.set_item("particles", summary.particles)?;
    out.set_item("time", summary.time)?;
    out.set_item("wall_seconds", summary.wall_seconds)?;
    out.set_item("directory", dir)?;
    Ok(out)
}

/// A run's message with the command that goes on from its checkpoint, which ends it
/// (`pmpm run FILE --resume CHECKPOINT [--output DIR]`), as the call that does so from Python.
fn python_resume(message: String, file: &str, dir: &Path) -> String {
    match message.find(&format!("pmpm run {file} --resume ")) {
        Some(at) => format!(
            "{}pmpm.run(deck, {:?}, resume={:?})",
            &message[..at],
            dir.display().to_string(),
            dir.join("checkpoint.bin").display().to_string()
        ),
        None => message,
    }
}

/// Reads a deck file into a dict of its keys as written (no defaults filled in), to change
/// and give to `Simulation` or `run`. Raises `pmpm.DeckError` on a TOML syntax error.
#[pyfunction]
fn read_deck<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyAny>> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(&path)
        .map_err(|e| PyOSError::new_err(format!("{file}: cannot read the deck: {e}")))?;
    let table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| DeckError::new_err(format!("{file}: {}", e.message())))?;
    to_py(py, &toml::Value::Table(table))
}

#[pymodule]
fn _pmpm(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<Simulation>()?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(read_deck, m)?)?;
    m.add("DeckError", py.get_type::<DeckError>())?;
    m.add("SolverError", py.get_type::<SolverError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
