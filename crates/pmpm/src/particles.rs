//! Material points, stored as a struct of arrays, and their creation from the deck's bodies.

use crate::grid::Vector;
use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

/// Initial stress state of a body.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InitialStress {
    /// p = rho |g| (H - y) below the body's top H.
    Hydrostatic,
}

/// D x D matrix of f64.
pub type Matrix<const D: usize> = SMatrix<f64, D, D>;

/// One per-particle value as a checkpoint stores it: flattened to plain numbers.
pub trait FieldValue: Copy {
    /// The plain number a value is stored as.
    type Flat: Copy + std::fmt::Debug + Serialize + for<'de> Deserialize<'de>;
    /// Numbers per value.
    const WIDTH: usize;
    /// The values as plain numbers, a matrix by columns.
    fn flatten(values: &[Self]) -> Vec<Self::Flat>;
    /// The values back from plain numbers (a length of a multiple of `WIDTH`).
    fn unflatten(flat: &[Self::Flat]) -> Vec<Self>;
    /// Whether every number is finite (integers always are).
    fn all_finite(flat: &[Self::Flat]) -> bool;
    /// Number `k` (below `WIDTH`) of one value, in the order of `flatten`.
    fn component(&self, k: usize) -> Self::Flat;
}

/// A per-particle field serialised as the `Vec` of plain numbers that `flatten` would give,
/// without making that copy: a checkpoint of a large run then costs no second copy of the
/// particle state in memory.
pub struct FlatSlice<'a, T>(pub &'a [T]);

impl<T: FieldValue> Serialize for FlatSlice<'_, T> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeSeq;
        let mut seq = serializer.serialize_seq(Some(self.0.len() * T::WIDTH))?;
        for value in self.0 {
            for k in 0..T::WIDTH {
                seq.serialize_element(&value.component(k))?;
            }
        }
        seq.end()
    }
}

impl FieldValue for f64 {
    type Flat = f64;
    const WIDTH: usize = 1;
    fn flatten(values: &[Self]) -> Vec<f64> {
        values.to_vec()
    }
    fn unflatten(flat: &[f64]) -> Vec<Self> {
        flat.to_vec()
    }
    fn all_finite(flat: &[f64]) -> bool {
        flat.iter().all(|a| a.is_finite())
    }
    fn component(&self, _: usize) -> f64 {
        *self
    }
}

/// Integer fields (ids, material indices) are stored as they are.
macro_rules! integer_field {
    ($($t:ty),*) => {$(
        impl FieldValue for $t {
            type Flat = $t;
            const WIDTH: usize = 1;
            fn flatten(values: &[Self]) -> Vec<$t> {
                values.to_vec()
            }
            fn unflatten(flat: &[$t]) -> Vec<Self> {
                flat.to_vec()
            }
            fn all_finite(_: &[$t]) -> bool {
                true
            }
            fn component(&self, _: usize) -> $t {
                *self
            }
        }
    )*};
}
integer_field!(u16, u32);

/// Vectors (R x 1) and matrices, by columns.
impl<const R: usize, const C: usize> FieldValue for SMatrix<f64, R, C> {
    type Flat = f64;
    const WIDTH: usize = R * C;
    fn flatten(values: &[Self]) -> Vec<f64> {
        values.iter().flat_map(|a| a.iter().copied()).collect()
    }
    fn unflatten(flat: &[f64]) -> Vec<Self> {
        flat.chunks_exact(R * C)
            .map(Self::from_column_slice)
            .collect()
    }
    fn all_finite(flat: &[f64]) -> bool {
        flat.iter().all(|a| a.is_finite())
    }
    fn component(&self, k: usize) -> f64 {
        self.as_slice()[k]
    }
}

/// One particle field as raw bytes ([`Particles::for_each_stored_field`]): an exchange between
/// ranks packs the values of the particles that leave, and puts those that arrive in their
/// places, a field at a time, so that its buffers hold one field of the moving particles, not
/// all of them.
pub trait ParticleField {
    /// The bytes of one value.
    fn value_size(&self) -> usize;
    /// Appends the values at the places `at` to `out`. No allocation once `out` has room.
    fn pack(&self, at: &[u32], out: &mut Vec<u8>);
    /// Keeps the values at the places `kept` (increasing), in that order.
    fn keep(&mut self, kept: &[u32]);
    /// The number of values.
    fn count(&self) -> usize;
    /// Appends `n` zero values, for [`ParticleField::unpack_at`] to fill.
    fn grow(&mut self, n: usize);
    /// Puts the values that [`ParticleField::pack`] wrote into `bytes` on a rank of the same
    /// run, a whole number of them, at the places from `at` on.
    fn unpack_at(&mut self, at: usize, bytes: &[u8]);
}

impl<T: bytemuck::Pod> ParticleField for Vec<T> {
    fn value_size(&self) -> usize {
        std::mem::size_of::<T>()
    }
    fn pack(&self, at: &[u32], out: &mut Vec<u8>) {
        for &p in at {
            out.extend_from_slice(bytemuck::bytes_of(&self[p as usize]));
        }
    }
    fn keep(&mut self, kept: &[u32]) {
        keep(self, kept);
    }
    fn count(&self) -> usize {
        self.len()
    }
    fn grow(&mut self, n: usize) {
        self.resize(self.len() + n, T::zeroed());
    }
    fn unpack_at(&mut self, at: usize, bytes: &[u8]) {
        let size = std::mem::size_of::<T>();
        debug_assert_eq!(bytes.len() % size, 0);
        let values = bytes
            .chunks_exact(size)
            .map(bytemuck::pod_read_unaligned::<T>);
        for (v, value) in self[at..].iter_mut().zip(values) {
            *v = value;
        }
    }
}

/// Declares the particle fields once: the struct of arrays [`Particles`], its reordering and
/// trimming, and [`FlatParticles`], the same arrays as plain numbers for the checkpoint, with
/// their length and finiteness checks. A field added here is sorted, checkpointed and checked
/// with the others.
macro_rules! particle_fields {
    ($($(#[doc = $doc:literal])+ $name:ident: $ty:ty,)+) => {
        /// All particles, one array per field. The arrays are sorted by cell from time to time
        /// ([`Particles::permute`]) so that the transfers walk the grid in order; `id` keeps
        /// each particle's number from its creation, and the output lists particles by it.
        #[derive(Debug, Clone, Default)]
        pub struct Particles<const D: usize> {
            $($(#[doc = $doc])+ pub $name: Vec<$ty>,)+
            /// Which of the optional fields (`deformation`, `tau`) the arrays hold: those the
            /// run's materials need ([`Particles::set_stored`]); the others are empty.
            pub stored: Stored,
        }

        /// The particle arrays as plain numbers, in the order of [`Particles`]: what a
        /// checkpoint stores.
        #[derive(Debug, Clone, Default, Serialize, Deserialize)]
        pub struct FlatParticles<const D: usize> {
            $($(#[doc = $doc])+ pub $name: Vec<<$ty as FieldValue>::Flat>,)+
        }

        impl<const D: usize> Particles<D> {
    /// The mass-weighted mean of `q` over the particles within `h` of `at` along every axis,
    /// with the linear hat weights N(x) = prod_d (1 - |x_d - a_d| / h), and their weighted
    /// mass (0: no material there). What the pressure and velocity gauges and the probes
    /// with `sample = "particles"` read: an average over the particles of about four cells
    /// (2D), smoother than the nodes' values where a few particles strike a wall.
    pub fn hat_mean(
        &self,
        at: &Vector<D>,
        h: f64,
        q: impl Fn(usize) -> Vector<D>,
    ) -> (f64, Vector<D>) {
        let (m, sum) = self.hat_sums(at, h, q);
        (m, if m > 0.0 { sum / m } else { sum })
    }

    /// The sums of [`Particles::hat_mean`]: the weighted mass, and the mass-weighted sum of
    /// `q` (a run over ranks adds them up over the ranks before it divides).
    pub fn hat_sums(
        &self,
        at: &Vector<D>,
        h: f64,
        q: impl Fn(usize) -> Vector<D>,
    ) -> (f64, Vector<D>) {
        let (mut m, mut sum) = (0.0, Vector::<D>::zeros());
        for p in 0..self.len() {
            let mut w = 1.0;
            for d in 0..D {
                w *= (1.0 - (self.x[p][d] - at[d]).abs() / h).max(0.0);
            }
            if w > 0.0 {
                m += w * self.mass[p];
                sum += q(p) * (w * self.mass[p]);
            }
        }
        (m, sum)
    }

            /// Reorders every array so that the particle at place `order[k]` moves to place k.
            pub fn permute(&mut self, order: &[u32], scratch: &mut PermuteScratch<D>) {
                $(permute(&mut self.$name, order, scratch);)+
            }

            /// Keeps the particles at the places `kept` (increasing), in that order, and drops
            /// the others: those an outflow face let out.
            pub fn keep(&mut self, kept: &[u32]) {
                $(keep(&mut self.$name, kept);)+
            }

            /// A copy of the particles at the places `at`, in that order.
            pub fn pick(&self, at: &[u32]) -> Self {
                Self {
                    $($name: pick(&self.$name, at),)+
                    stored: self.stored,
                }
            }

            /// Keeps the first `n` particles.
            pub fn truncate(&mut self, n: usize) {
                $(self.$name.truncate(n);)+
            }

            /// Room for `extra` more particles in every array the run stores.
            pub fn reserve(&mut self, extra: usize) {
                $(if !self.$name.is_empty() {
                    self.$name.reserve_exact(extra);
                })+
            }

            /// Calls `f` on each field the run stores, in the order of [`Particles`], as raw
            /// bytes ([`ParticleField`]): what the exchanges between ranks of the same run
            /// send, one field at a time.
            pub fn for_each_stored_field(&mut self, mut f: impl FnMut(&mut dyn ParticleField)) {
                $(if self.stored.holds(stringify!($name)) {
                    f(&mut self.$name);
                })+
            }

            fn append_fields(&mut self, other: &mut Self) {
                $(self.$name.append(&mut other.$name);)+
            }

            /// Gives back the arrays' unused capacity.
            pub fn shrink_to_fit(&mut self) {
                $(self.$name.shrink_to_fit();)+
            }

            /// The arrays as plain numbers.
            pub fn flatten(&self) -> FlatParticles<D> {
                FlatParticles {
                    $($name: <$ty as FieldValue>::flatten(&self.$name),)+
                }
            }

            /// The arrays as [`flatten`](Self::flatten) gives them, for serialisation, without
            /// copying them.
            pub fn flat_view(&self) -> FlatView<'_, D> {
                FlatView(self)
            }

            /// The arrays back from plain numbers whose lengths
            /// ([`FlatParticles::lengths`]) are right.
            pub fn unflatten(flat: &FlatParticles<D>) -> Self {
                Self {
                    $($name: <$ty as FieldValue>::unflatten(&flat.$name),)+
                    stored: Stored::default(),
                }
            }
        }

        /// The particle arrays, serialised exactly as their [`FlatParticles`] would be.
        pub struct FlatView<'a, const D: usize>(&'a Particles<D>);

        impl<const D: usize> Serialize for FlatView<'_, D> {
            fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
                use serde::ser::SerializeStruct;
                let fields = [$(stringify!($name)),+].len();
                let mut s = serializer.serialize_struct("FlatParticles", fields)?;
                $(s.serialize_field(stringify!($name), &FlatSlice(&self.0.$name))?;)+
                s.end()
            }
        }

        impl<const D: usize> FlatParticles<D> {
            /// Each field's name, the numbers it holds and the numbers `n` particles need,
            /// for a run that stores the optional fields `stored` says. An optional field the
            /// run does not store may be empty, or full (a checkpoint of a build that stored
            /// every field): [`Particles::set_stored`] drops it.
            pub fn lengths(&self, n: usize, stored: Stored) -> Vec<(&'static str, usize, usize)> {
                vec![$({
                    let (name, got) = (stringify!($name), self.$name.len());
                    let full = n * <$ty as FieldValue>::WIDTH;
                    let want = if !stored.holds(name) && got == 0 { 0 } else { full };
                    (name, got, want)
                },)+]
            }

            /// The first field holding a number that is not finite.
            pub fn non_finite(&self) -> Option<&'static str> {
                $(if !<$ty as FieldValue>::all_finite(&self.$name) {
                    return Some(stringify!($name));
                })+
                None
            }
        }
    };
}

particle_fields! {
    /// Number of the particle at this place, in creation order (0 to n - 1).
    id: u32,
    /// Position x_p.
    x: Vector<D>,
    /// Velocity v_p.
    v: Vector<D>,
    /// Mass m_p.
    mass: f64,
    /// Initial volume V_p^0.
    volume0: f64,
    /// Volume ratio J = V_p / V_p^0.
    jacobian: f64,
    /// Deformation gradient F_p.
    deformation: Matrix<D>,
    /// Pressure p_p (positive in compression).
    pressure: f64,
    /// Deviatoric Cauchy stress tau_p.
    tau: Matrix<D>,
    /// Velocity gradient L_p of the last grid-to-particle transfer.
    velocity_gradient: Matrix<D>,
    /// APIC affine matrix C_p.
    affine: Matrix<D>,
    /// Index into the deck's materials.
    material: u16,
    /// GIMP half-width of the particle domain, in cells.
    half_width: f64,
}

/// The optional per-particle fields a run stores: each only where a material of the run reads
/// it. A Newtonian or viscoplastic fluid's deviatoric stress is a function of its velocity
/// gradient alone (the material module computes it from L where it is needed), and
/// its deformation gradient is read by nothing: F and tau are 2 D^2
/// numbers per particle (64 B in 2D, 144 B in 3D) that a water run need not keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stored {
    /// F_p: a material whose stress reads it (the neo-Hookean solid).
    pub deformation: bool,
    /// tau_p: a material whose stress has a history (a solid, elastic or plastic).
    pub stress: bool,
}

impl Default for Stored {
    /// Every field: what a particle set built field by field (a test, a checkpoint just read)
    /// holds until [`Particles::set_stored`] says otherwise.
    fn default() -> Self {
        Self {
            deformation: true,
            stress: true,
        }
    }
}

impl Stored {
    /// How many of the optional fields (each a D x D matrix per particle) are left out.
    pub fn unstored(&self) -> usize {
        usize::from(!self.deformation) + usize::from(!self.stress)
    }

    /// Whether the field `name` is held (every field that is not optional is).
    pub fn holds(&self, name: &str) -> bool {
        match name {
            "deformation" => self.deformation,
            "tau" => self.stress,
            _ => true,
        }
    }
}

impl<const D: usize> Particles<D> {
    /// Keeps the optional fields `stored` names, F = I and tau = 0 where they were not held,
    /// and drops the others' arrays.
    pub fn set_stored(&mut self, stored: Stored) {
        let n = self.len();
        self.stored = stored;
        if stored.deformation {
            self.deformation.resize(n, Matrix::<D>::identity());
        } else {
            self.deformation = Vec::new();
        }
        if stored.stress {
            self.tau.resize(n, Matrix::<D>::zeros());
        } else {
            self.tau = Vec::new();
        }
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Current volume V_p = J V_p^0.
    #[inline]
    pub fn volume(&self, p: usize) -> f64 {
        self.jacobian[p] * self.volume0[p]
    }

    /// Places of the particles in id order: `places()[k]` is where the particle with the
    /// k-th smallest id is stored (particle k while none has left or entered the run).
    pub fn places(&self) -> Vec<usize> {
        let mut at: Vec<usize> = (0..self.len()).collect();
        at.sort_unstable_by_key(|&p| self.id[p]);
        at
    }

    /// Appends `other`'s particles, leaving its arrays empty (their room kept).
    pub fn append(&mut self, other: &mut Self) {
        self.append_fields(other);
    }

    /// A copy of a per-particle field in id order.
    pub fn by_id<T: Copy>(&self, field: &[T]) -> Vec<T> {
        self.places().iter().map(|&p| field[p]).collect()
    }
}

/// Work space of [`Particles::permute`]: one bit per particle, kept between sorts so that a
/// sort allocates nothing once it has grown. The permutation is applied in place, cycle by
/// cycle, so a sort needs no second copy of the particle arrays (which would cost as much
/// memory as the matrix fields themselves).
#[derive(Debug, Default)]
pub struct PermuteScratch<const D: usize> {
    done: Vec<u64>,
}

/// Keeps `field[kept[k]]` at place k and drops the rest (`kept` increasing, so each value
/// moves down or stays: in place, without a second array). An optional field the run does not
/// store is empty and stays so.
pub fn keep<T: Copy>(field: &mut Vec<T>, kept: &[u32]) {
    if field.is_empty() {
        return;
    }
    for (k, &i) in kept.iter().enumerate() {
        field[k] = field[i as usize];
    }
    field.truncate(kept.len());
}

/// `field[at[k]]` for every k (empty where the field is: one the run does not store).
fn pick<T: Copy>(field: &[T], at: &[u32]) -> Vec<T> {
    if field.is_empty() {
        return Vec::new();
    }
    at.iter().map(|&i| field[i as usize]).collect()
}

/// `field[k] = old field[order[k]]` in place (`order` a permutation of the indices).
///
/// Serial: it runs every `sort_interval` steps and costs a few nanoseconds per particle and
/// field, against microseconds per particle for a step.
pub fn permute<T: Copy, const D: usize>(
    field: &mut [T],
    order: &[u32],
    scratch: &mut PermuteScratch<D>,
) {
    let done = &mut scratch.done;
    done.clear();
    done.resize(field.len().div_ceil(64), 0);
    for start in 0..field.len() {
        if done[start / 64] >> (start % 64) & 1 == 1 {
            continue;
        }
        let first = field[start];
        let mut j = start;
        loop {
            done[j / 64] |= 1 << (j % 64);
            let src = order[j] as usize;
            if src == start {
                field[j] = first;
                break;
            }
            field[j] = field[src];
            j = src;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permute_moves_each_element_to_its_new_place() {
        // two cycles and a fixed point
        let order = [3u32, 0, 2, 1, 5, 4];
        let mut field = vec![10, 11, 12, 13, 14, 15];
        permute(&mut field, &order, &mut PermuteScratch::<2>::default());
        assert_eq!(field, vec![13, 10, 12, 11, 15, 14]);
    }

    /// Particles packed as bytes (what migrates between ranks) come back as they were, the
    /// optional fields the run does not store left out on both sides.
    #[test]
    fn packed_particles_come_back_as_they_were() {
        let mut rnd = crate::test_random(9);
        let n = 7;
        let mut ps = Particles::<3> {
            id: (0..n as u32).collect(),
            x: (0..n)
                .map(|_| Vector::<3>::new(rnd(), rnd(), rnd()))
                .collect(),
            v: (0..n)
                .map(|_| Vector::<3>::new(rnd(), rnd(), rnd()))
                .collect(),
            mass: (0..n).map(|_| rnd()).collect(),
            volume0: (0..n).map(|_| rnd()).collect(),
            jacobian: (0..n).map(|_| rnd()).collect(),
            pressure: (0..n).map(|_| rnd()).collect(),
            velocity_gradient: (0..n).map(|_| Matrix::<3>::from_fn(|_, _| rnd())).collect(),
            affine: (0..n).map(|_| Matrix::<3>::from_fn(|_, _| rnd())).collect(),
            material: (0..n as u16).collect(),
            half_width: (0..n).map(|_| rnd()).collect(),
            ..Particles::default()
        };
        ps.set_stored(Stored {
            deformation: false,
            stress: true,
        });
        ps.tau = (0..n).map(|_| Matrix::<3>::from_fn(|_, _| rnd())).collect();
        let at = [5u32, 1, 6];
        let mut back = Particles::<3> {
            stored: ps.stored,
            ..Particles::default()
        };
        let mut fields = Vec::new();
        ps.for_each_stored_field(|f| {
            let mut bytes = Vec::new();
            f.pack(&at, &mut bytes);
            assert_eq!(bytes.len(), at.len() * f.value_size());
            fields.push(bytes);
        });
        let mut next = fields.iter();
        back.for_each_stored_field(|f| {
            f.grow(at.len());
            f.unpack_at(0, next.next().unwrap());
        });
        assert!(next.next().is_none());
        let want = ps.pick(&at);
        assert_eq!(back.len(), 3);
        assert!(back.deformation.is_empty());
        assert_eq!(format!("{back:?}"), format!("{want:?}"));
    }
}
