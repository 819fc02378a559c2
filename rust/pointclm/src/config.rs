//! Every threshold of the method, named, with the paper's synthetic-scale defaults.

use crate::error::{Error, Result};

/// Gives an enum of plain variants the names a config read by name uses (the Python
/// binding's `"paper"`, `"kmeans"`, ...): `NAMES`, `name` and `from_name`, and its
/// [`FieldType`] as a [`Kind::Choice`] among those names.
macro_rules! named_choices {
    ($ty:ident { $($variant:ident = $name:literal),+ $(,)? }) => {
        impl $ty {
            /// The variants' names, in declaration order.
            pub const NAMES: &'static [&'static str] = &[$($name),+];

            /// This variant's name.
            pub fn name(self) -> &'static str {
                match self {
                    $(Self::$variant => $name,)+
                }
            }

            /// The variant called `name`, if any.
            pub fn from_name(name: &str) -> Option<Self> {
                match name {
                    $($name => Some(Self::$variant),)+
                    _ => None,
                }
            }
        }

        impl FieldType for $ty {
            const KIND: Kind = Kind::Choice(Self::NAMES);

            fn to_value(&self) -> Value {
                Value::Choice(self.name())
            }

            fn from_value(value: Value) -> Option<Self> {
                match value {
                    Value::Choice(name) => Self::from_name(name),
                    _ => None,
                }
            }
        }
    };
}

/// How density pruning decides that a correspondence lies in a dense (inlier) region.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pruning {
    /// The paper's form: `S = S^F * beta` (or `S = beta` without features), binarised at
    /// `tau_s`; keep row `i` if its row sum (itself included) exceeds `tau_n`.
    Paper,
    /// The authors' code: count `j` with `beta_ij > beta_threshold` and, with features,
    /// `S^F_ij > feature_threshold`; keep `i` if the count (itself included) exceeds `min_count`.
    AuthorsCode,
    /// No pruning: every correspondence goes to clustering (paper Table 3 ablation).
    Disabled,
}

named_choices!(Pruning {
    Paper = "paper",
    AuthorsCode = "authors",
    Disabled = "none",
});

/// How rows of the spectral embedding are turned into cluster labels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Assignment {
    /// k-means++ with restarts on the row-normalised embedding (Ng, Jordan and Weiss).
    KMeans,
    /// Yu and Shi's discretisation, as scikit-learn's `assign_labels="discretize"`
    /// that the authors' code uses.
    Discretize,
}

named_choices!(Assignment {
    KMeans = "kmeans",
    Discretize = "discretize",
});

/// What a field of [`Config`] holds, for code that reads or writes configs by field name
/// (the Python binding, a file format): see [`Config::FIELDS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A real number (`f64`).
    Float,
    /// A count (`usize`).
    Count,
    /// `true` or `false`.
    Bool,
    /// One of these names (an enum such as [`Pruning`]).
    Choice(&'static [&'static str]),
}

/// Whether a field of [`Config`] is a length, in the units of the points, which
/// [`Config::scaled`] multiplies, or a unitless level, count or switch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// In the units of the points; scaled with the data.
    Length,
    /// Unitless: kept as it is when the data is scaled.
    Unitless,
}

/// The description of one field of [`Config`], an entry of [`Config::FIELDS`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Field {
    /// The field's name, as written in Rust and in the Python binding.
    pub name: &'static str,
    /// Its documentation (the field's doc comment, one line per source line).
    pub doc: &'static str,
    /// What it holds.
    pub kind: Kind,
    /// Whether it may be unset (`Option<_>`, `None` in Python).
    pub optional: bool,
    /// Length or unitless.
    pub unit: Unit,
    /// The closed range `[lo, hi]` its value must lie in (a count's as whole numbers), or
    /// `None` where the struct's own checks say what is valid.
    pub range: Option<(f64, f64)>,
}

impl Field {
    /// Whether `value` lies in the field's range (an unset optional field always does).
    pub fn admits(&self, value: Value) -> bool {
        let Some((lo, hi)) = self.range else {
            return true;
        };
        match value {
            Value::Float(v) => v >= lo && v <= hi,
            Value::Count(n) => (n as f64) >= lo && (n as f64) <= hi,
            _ => true,
        }
    }
}

/// The value of one field of [`Config`], read or written by name ([`Config::get`],
/// [`Config::set`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    /// An unset optional field.
    None,
    /// A [`Kind::Float`] value.
    Float(f64),
    /// A [`Kind::Count`] value.
    Count(usize),
    /// A [`Kind::Bool`] value.
    Bool(bool),
    /// A [`Kind::Choice`] value, by name.
    Choice(&'static str),
}

impl std::fmt::Display for Value {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Value::None => write!(f, "None"),
            Value::Float(v) => write!(f, "{v}"),
            Value::Count(n) => write!(f, "{n}"),
            Value::Bool(b) => write!(f, "{b}"),
            Value::Choice(s) => write!(f, "{s:?}"),
        }
    }
}

/// A type a field of [`Config`] may have, with its [`Kind`] and its conversion to and from a
/// [`Value`].
pub trait FieldType: Sized {
    /// What the field holds.
    const KIND: Kind;
    /// Whether it may be unset.
    const OPTIONAL: bool = false;
    /// The value, by kind.
    fn to_value(&self) -> Value;
    /// A value of this type, or `None` if `value` is of another kind.
    fn from_value(value: Value) -> Option<Self>;
}

impl FieldType for f64 {
    const KIND: Kind = Kind::Float;

    fn to_value(&self) -> Value {
        Value::Float(*self)
    }

    fn from_value(value: Value) -> Option<Self> {
        match value {
            Value::Float(v) => Some(v),
            _ => None,
        }
    }
}

impl FieldType for usize {
    const KIND: Kind = Kind::Count;

    fn to_value(&self) -> Value {
        Value::Count(*self)
    }

    fn from_value(value: Value) -> Option<Self> {
        match value {
            Value::Count(v) => Some(v),
            _ => None,
        }
    }
}

impl FieldType for bool {
    const KIND: Kind = Kind::Bool;

    fn to_value(&self) -> Value {
        Value::Bool(*self)
    }

    fn from_value(value: Value) -> Option<Self> {
        match value {
            Value::Bool(v) => Some(v),
            _ => None,
        }
    }
}

impl<T: FieldType> FieldType for Option<T> {
    const KIND: Kind = T::KIND;
    const OPTIONAL: bool = true;

    fn to_value(&self) -> Value {
        self.as_ref().map_or(Value::None, T::to_value)
    }

    fn from_value(value: Value) -> Option<Self> {
        match value {
            Value::None => Some(None),
            v => T::from_value(v).map(Some),
        }
    }
}

/// A struct of parameters declared with `config!`: its fields described one by one
/// ([`Declared::FIELDS`]) and read or written by name, which is what code that works by field
/// name (the Python binding, the CLI, a file format) builds on, so that a field is declared in
/// one place.
pub trait Declared: Default + Clone {
    /// Every field, in declaration order, with its doc, kind, unit and range.
    const FIELDS: &'static [Field];
    /// Every field with its value, in declaration order.
    fn values(&self) -> Vec<(&'static Field, Value)>;
    /// The value of the field called `name`, if there is one.
    fn get(&self, name: &str) -> Option<Value>;
    /// Sets the field called `name` to `value`; `false` (and nothing set) if there is no such
    /// field or `value` is of another kind. No range is checked here.
    #[must_use]
    fn set(&mut self, name: &str, value: Value) -> bool;

    /// The first field whose value lies outside its declared range ([`Field::range`]), with
    /// that value; `None` when every field is within its range.
    fn out_of_range(&self) -> Option<(&'static Field, Value)> {
        self.values().into_iter().find(|(f, v)| !f.admits(*v))
    }

    /// The same settings with every [`Unit::Length`] field multiplied by `factor`.
    fn scaled(&self, factor: f64) -> Self {
        let mut scaled = self.clone();
        for (field, value) in self.values() {
            if let (Unit::Length, Value::Float(v)) = (field.unit, value) {
                let set = scaled.set(field.name, Value::Float(v * factor));
                debug_assert!(set, "{} is a float field", field.name);
            }
        }
        scaled
    }
}

/// Declares a struct of parameters from one list, each field written once with its doc, type,
/// default, unit and (optionally) its closed range `[lo, hi]`, and derives from it `Default`
/// and [`Declared`]: the table of fields and access by name, which the Python binding,
/// `scaled` and the range checks use.
macro_rules! config {
    (@range) => { None };
    (@range $lo:expr, $hi:expr) => { Some(($lo as f64, $hi as f64)) };
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $(
                $(#[doc = $doc:literal])*
                pub $field:ident: $ty:ty = $default:expr => $unit:expr $(, [$lo:expr, $hi:expr])?;
            )+
        }
    ) => {
        $(#[$meta])*
        pub struct $name {
            $(
                $(#[doc = $doc])*
                pub $field: $ty,
            )+
        }

        impl Default for $name {
            fn default() -> Self {
                Self {
                    $($field: $default,)+
                }
            }
        }

        impl $crate::config::Declared for $name {
            const FIELDS: &'static [$crate::config::Field] = &[$(
                $crate::config::Field {
                    name: stringify!($field),
                    doc: concat!($($doc, "\n"),*),
                    kind: <$ty as $crate::config::FieldType>::KIND,
                    optional: <$ty as $crate::config::FieldType>::OPTIONAL,
                    unit: $unit,
                    range: $crate::config::config!(@range $($lo, $hi)?),
                },
            )+];

            fn values(&self) -> Vec<(&'static $crate::config::Field, $crate::config::Value)> {
                Self::FIELDS
                    .iter()
                    .zip([$($crate::config::FieldType::to_value(&self.$field)),+])
                    .collect()
            }

            fn get(&self, name: &str) -> Option<$crate::config::Value> {
                match name {
                    $(stringify!($field) => Some($crate::config::FieldType::to_value(&self.$field)),)+
                    _ => None,
                }
            }

            fn set(&mut self, name: &str, value: $crate::config::Value) -> bool {
                match name {
                    $(stringify!($field) => {
                        match <$ty as $crate::config::FieldType>::from_value(value) {
                            Some(v) => {
                                self.$field = v;
                                true
                            }
                            None => false,
                        }
                    })+
                    _ => false,
                }
            }
        }
    };
}
pub(crate) use config;

config! {
    /// Parameters of the whole pipeline.
    ///
    /// Lengths (`sigma_d`, `affinity_sigma`, `inlier_threshold`) are in the units of the
    /// points. The defaults are the paper's synthetic settings, where shapes fit in a unit
    /// sphere and the noise is about 0.01; [`Config::scaled`] multiplies every length for data
    /// at another scale. Each field is declared once, below, with its default and unit;
    /// [`Config::FIELDS`] describes them to code that works by name (the Python binding).
    #[derive(Debug, Clone, PartialEq)]
    pub struct Config {
        /// Length tolerance of spatial consistency `beta_ij = [1 - d_ij^2 / sigma_d^2]_+`.
        pub sigma_d: f64 = 0.05 => Unit::Length;
        /// Pruning rule; see [`Pruning`]. "paper": binarise `S` at `tau_s`, keep rows whose
        /// sum exceeds `tau_n`. "authors": the authors' code, `beta > beta_threshold` (and
        /// feature similarity `> feature_threshold`), keep rows whose count exceeds
        /// `min_count`. "none": no pruning (ablation).
        pub pruning: Pruning = Pruning::Paper => Unit::Unitless;
        /// Paper rule: binarisation threshold on `S`.
        pub tau_s: f64 = 0.85 => Unit::Unitless;
        /// Paper rule: a row must have more than this many entries above `tau_s`.
        pub tau_n: usize = 10 => Unit::Unitless;
        /// Authors'-code rule: threshold on `beta`.
        pub beta_threshold: f64 = 0.9 => Unit::Unitless;
        /// Authors'-code rule: threshold on the feature similarity `S^F` (ignored without
        /// features).
        pub feature_threshold: f64 = 0.8 => Unit::Unitless;
        /// Authors'-code rule: a row must count more than this many consistent
        /// correspondences.
        pub min_count: usize = 9 => Unit::Unitless;
        /// Upper bound on the kept set handed to the dense eigensolver: when pruning keeps
        /// more, the densest `max_kept` rows are clustered (memory and time grow as its
        /// square and cube).
        pub max_kept: usize = 2000 => Unit::Unitless;
        /// Length scale of the clustering affinity `[1 - d_ij^2 / affinity_sigma^2]_+`.
        pub affinity_sigma: f64 = 0.1 => Unit::Length;
        /// Optional cap on the number of clusters the eigengap may choose.
        pub max_instances: Option<usize> = None => Unit::Unitless;
        /// When set, the cluster count is the larger of the eigengap's and the number of
        /// normalised-Laplacian eigenvalues below this level (in (0, 2)). Why: with dozens of
        /// similar copies the spectrum rises smoothly and its largest gap comes early, while
        /// every copy still contributes an eigenvalue well below 1 (a group with more affinity
        /// inside than across has a small Rayleigh quotient). `None`: the eigengap alone (the
        /// paper's rule).
        pub cluster_level: Option<f64> = None => Unit::Unitless;
        /// Clustering rounds: after each, the correspondences explained by validated instances
        /// leave the kept set and the rest is clustered again, which finds copies the eigengap
        /// merged or missed (bins of dozens of parts). Needs `max_nfa` (without validation one
        /// round runs, as in the paper).
        pub max_rounds: usize = 1 => Unit::Unitless;
        /// Label assignment on the spectral embedding: "kmeans", k-means++ on the
        /// row-normalised embedding, or "discretize", Yu and Shi's discretisation; see
        /// [`Assignment`].
        pub assignment: Assignment = Assignment::KMeans => Unit::Unitless;
        /// Restarts of k-means (best inertia wins) or of the discretisation.
        pub kmeans_restarts: usize = 10 => Unit::Unitless;
        /// Instances with fewer inliers are dropped (checked after the labelling and again
        /// after the final refit). Clusters only seed poses: any cluster of 3 or more rows is
        /// fitted (`clustering::MIN_SEED_ROWS`), since its pose may explain more rows.
        pub min_cluster_size: usize = 10 => Unit::Unitless;
        /// At most this many RANSAC hypotheses (3-point Kabsch) per cluster.
        pub ransac_iterations: usize = 1000 => Unit::Unitless;
        /// RANSAC stops once an all-inlier sample would have been drawn with this probability
        /// at the best inlier share found so far (1 runs all `ransac_iterations`). 0.9999:
        /// on the validation sets no worse than running every hypothesis (synthetic scores
        /// identical), the correspondence stage in about half the time (BENCHMARKS.md).
        pub ransac_confidence: f64 = 0.9999 => Unit::Unitless;
        /// A-contrario validation: an instance is kept only if its number of false alarms (how
        /// many poses as well supported would arise from unrelated matches) is at most this
        /// ([`crate::validation`]). `None` keeps every instance.
        pub max_nfa: Option<f64> = Some(1e-3) => Unit::Unitless;
        /// A correspondence is an inlier of a pose if `||R x + t - y||` is below this.
        pub inlier_threshold: f64 = 0.1 => Unit::Length;
        /// Refit each pose by least squares on its inliers (the authors' code does not).
        pub refine: bool = true => Unit::Unitless;
        /// Merge instances whose poses place the object at the same spot (the authors' code
        /// returns such duplicates).
        pub merge_duplicates: bool = true => Unit::Unitless;
    }
}

fn invalid(field: &'static str, value: impl ToString, reason: &'static str) -> Error {
    Error::InvalidConfig {
        field,
        value: value.to_string(),
        reason,
    }
}

fn positive_length(field: &'static str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, v, "must be a finite length > 0"))
    }
}

/// Upper bounds of the count fields, enforced by [`Config::validate`]. Each lies far above
/// any useful setting; its purpose is that no config can ask for unbounded work or memory (a
/// service that passes user configs through must be able to rely on a finite worst case).
/// A new count field of [`Config`] gets its bound here and a line in `Config::counts`.
pub mod bounds {
    /// Rows the dense eigensolver may receive: memory grows as `8 n^2` bytes per matrix
    /// (3.2 GB at this bound) and time as `n^3`. The default is 2000.
    pub const MAX_KEPT: usize = 20_000;
    /// RANSAC hypotheses per cluster. The default is 50; a 3-point sample from a cluster
    /// with 10% inliers succeeds with probability 1 - 1e-9 within 2 * 10^4 draws.
    pub const RANSAC_ITERATIONS: usize = 1_000_000;
    /// Restarts of the label assignment (each costs one k-means or discretisation). The
    /// default is 10.
    pub const KMEANS_RESTARTS: usize = 10_000;
    /// Smallest cluster kept: no cluster can exceed the rows handed to clustering.
    pub const MIN_CLUSTER_SIZE: usize = MAX_KEPT;
    /// Clusters the eigengap may choose: at most one per clustered row.
    pub const MAX_INSTANCES: usize = MAX_KEPT;
    /// The density thresholds `tau_n` and `min_count`: row counts are 32-bit, so a larger
    /// threshold could never be met.
    pub const DENSITY_COUNT: usize = u32::MAX as usize;
    /// Clustering rounds: each costs at most one clustering of the kept set.
    pub const MAX_ROUNDS: usize = 100;
}

impl Config {
    /// `(field, value, min, max)` of every count field, checked by [`Config::validate`].
    fn counts(&self) -> [(&'static str, usize, usize, usize); 8] {
        [
            ("tau_n", self.tau_n, 0, bounds::DENSITY_COUNT),
            ("min_count", self.min_count, 0, bounds::DENSITY_COUNT),
            // a rigid pose needs 3 points
            (
                "min_cluster_size",
                self.min_cluster_size,
                3,
                bounds::MIN_CLUSTER_SIZE,
            ),
            ("max_kept", self.max_kept, 3, bounds::MAX_KEPT),
            (
                "max_instances",
                self.max_instances.unwrap_or(1),
                1,
                bounds::MAX_INSTANCES,
            ),
            (
                "kmeans_restarts",
                self.kmeans_restarts,
                1,
                bounds::KMEANS_RESTARTS,
            ),
            (
                "ransac_iterations",
                self.ransac_iterations,
                1,
                bounds::RANSAC_ITERATIONS,
            ),
            ("max_rounds", self.max_rounds, 1, bounds::MAX_ROUNDS),
        ]
    }

    /// The same settings with every length multiplied by `factor` (for data whose noise and
    /// object size are `factor` times the synthetic benchmark's).
    /// The lengths are the fields of [`Unit::Length`] in [`Config::FIELDS`].
    pub fn scaled(&self, factor: f64) -> Self {
        Declared::scaled(self, factor)
    }

    /// Every field, in declaration order ([`Declared::FIELDS`]).
    pub const FIELDS: &'static [Field] = <Self as Declared>::FIELDS;

    /// Every field with its value, in declaration order ([`Config::FIELDS`]).
    pub fn values(&self) -> Vec<(&'static Field, Value)> {
        Declared::values(self)
    }

    /// The value of the field called `name`, if there is one.
    pub fn get(&self, name: &str) -> Option<Value> {
        Declared::get(self, name)
    }

    /// Sets the field called `name` to `value`; `false` (and nothing set) if there is no such
    /// field or `value` is of another kind. No range is checked here: see
    /// [`Config::validate`].
    #[must_use]
    pub fn set(&mut self, name: &str, value: Value) -> bool {
        Declared::set(self, name, value)
    }

    /// Checks every field; the pipeline calls this before touching any data.
    pub fn validate(&self) -> Result<()> {
        positive_length("sigma_d", self.sigma_d)?;
        positive_length("affinity_sigma", self.affinity_sigma)?;
        positive_length("inlier_threshold", self.inlier_threshold)?;
        if !(self.tau_s.is_finite() && (-1.0..1.0).contains(&self.tau_s)) {
            return Err(invalid("tau_s", self.tau_s, "must lie in [-1, 1)"));
        }
        if !(self.beta_threshold.is_finite() && (0.0..1.0).contains(&self.beta_threshold)) {
            return Err(invalid(
                "beta_threshold",
                self.beta_threshold,
                "must lie in [0, 1)",
            ));
        }
        if !(self.feature_threshold.is_finite() && (-1.0..1.0).contains(&self.feature_threshold)) {
            return Err(invalid(
                "feature_threshold",
                self.feature_threshold,
                "must lie in [-1, 1)",
            ));
        }
        for (field, value, min, max) in self.counts() {
            if !(min..=max).contains(&value) {
                return Err(Error::ConfigOutOfRange {
                    field,
                    value: value as u128,
                    min,
                    max,
                });
            }
        }
        if self.max_kept < self.min_cluster_size {
            return Err(invalid(
                "max_kept",
                self.max_kept,
                "must be >= min_cluster_size",
            ));
        }
        if !(self.ransac_confidence.is_finite()
            && self.ransac_confidence > 0.0
            && self.ransac_confidence <= 1.0)
        {
            return Err(invalid(
                "ransac_confidence",
                self.ransac_confidence,
                "must lie in (0, 1]",
            ));
        }
        if let Some(v) = self.cluster_level {
            if !(v.is_finite() && v > 0.0 && v < 2.0) {
                return Err(invalid("cluster_level", v, "must lie in (0, 2) or be None"));
            }
        }
        if let Some(v) = self.max_nfa {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid("max_nfa", v, "must be a finite number > 0 or None"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "tests/config.rs"]
mod tests;
