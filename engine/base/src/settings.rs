//! One declaration per setting. [`settings!`](crate::settings!) declares a configuration
//! structure field by field: its type, default, documentation (both the
//! rustdoc and the text `latentam config --print-defaults` prints) and
//! valid range. The structure, its `Default`, its key documentation and
//! its range checks all come from that one declaration, so the printed
//! ranges are the checked ones.
//!
//! A field's type says how it is documented and checked through
//! [`Setting`]: numbers by their range, a nested settings structure as a
//! `[section]` of keys, an enum of choices by its own `Setting` impl.

/// Largest distance setting, metres: distances within a few kilometres,
/// so that no loop over space runs for ever and no count derived from a
/// distance overflows.
pub const MAX_DISTANCE: f64 = 5000.0;

/// What a documented key is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A `[section]`: a nested structure with keys of its own.
    Section,
    /// A value that is always present.
    Value,
    /// A value that may be unset (an `Option`); `example` is shown,
    /// commented out, when it is unset by default.
    Optional {
        /// What the printed defaults show for it.
        example: &'static str,
    },
    /// One of several variants (an enum), written as a one-key inline
    /// table `{ variant = payload }`; the variants are the entries below it.
    Choice,
    /// A variant of the `Choice` above it. `payload` (TOML) is what it
    /// starts from when selected by name or by one of its fields.
    Variant {
        /// Its starting value.
        payload: &'static str,
    },
    /// A field of a `Variant` whose payload is a table.
    VariantField,
}

/// The documentation of one key.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyDoc {
    /// Dotted path from the top of the configuration.
    pub key: String,
    /// What it is.
    pub kind: Kind,
    /// For users: meaning, unit and valid range.
    pub text: String,
}

/// A setting outside its documented range, as [`Setting::check_nested`]
/// finds it; as the engine's error it is [`Error::Config`](crate::Error::Config).
///
/// ```
/// use latentam_base::settings::OutOfRange;
///
/// let e = OutOfRange { key: "seeding.stride".into(), reason: "0 must be from 1 to 64".into() };
/// assert_eq!(e.to_string(), "seeding.stride 0 must be from 1 to 64");
/// let e: latentam_base::Error = e.into();
/// assert_eq!(e.to_string(), "setting `seeding.stride`: 0 must be from 1 to 64");
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OutOfRange {
    /// The dotted key of the setting.
    pub key: String,
    /// What is wrong with its value.
    pub reason: String,
}

impl std::fmt::Display for OutOfRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}", self.key, self.reason)
    }
}

impl From<OutOfRange> for crate::Error {
    fn from(e: OutOfRange) -> Self {
        crate::Error::config(e.key, e.reason)
    }
}

/// A value type of a setting: how it is documented and checked.
pub trait Setting {
    /// Whether the value is an integer (said in its range's text).
    const INTEGER: bool = false;

    /// The value as a number, for range checks; `None` for an unset
    /// optional value or a value that is not a number.
    fn number(&self) -> Option<f64> {
        None
    }

    /// The keys below this one (a section's fields, a choice's variants),
    /// appended to `out` under `prefix`.
    fn nested_docs(_prefix: &str, _out: &mut Vec<KeyDoc>) {}

    /// Checks the keys below this one; the error names the first
    /// offending key under `prefix`.
    fn check_nested(&self, _prefix: &str) -> Result<(), OutOfRange> {
        Ok(())
    }
}

macro_rules! number_setting {
    ($integer:expr => $($t:ty),*) => {$(
        impl Setting for $t {
            const INTEGER: bool = $integer;

            fn number(&self) -> Option<f64> {
                Some(*self as f64)
            }
        }
    )*};
}
number_setting!(true => u32, u64);
number_setting!(false => f64);

impl Setting for f32 {
    fn number(&self) -> Option<f64> {
        // Through the shortest decimal that reads back as this f32, so
        // that 0.005 or 1e30 are compared and shown as the user wrote
        // them, not as their binary widening.
        self.to_string().parse().ok()
    }
}

impl Setting for bool {}

impl Setting for String {}

impl<T: Setting> Setting for Option<T> {
    const INTEGER: bool = T::INTEGER;

    fn number(&self) -> Option<f64> {
        self.as_ref().and_then(Setting::number)
    }
}

/// A bound of a setting's range: a number or another setting's value.
pub enum Bound<C> {
    /// A fixed number.
    Number(f64),
    /// The value of the setting named (a sibling in the same structure).
    Setting(&'static str, fn(&C) -> f64),
    /// No bound but finiteness.
    Finite,
}

impl<C> Bound<C> {
    fn value(&self, config: &C) -> f64 {
        match self {
            Bound::Number(x) => *x,
            Bound::Setting(_, f) => f(config),
            Bound::Finite => f64::INFINITY,
        }
    }

    fn text(&self) -> String {
        match self {
            Bound::Number(x) => x.to_string(),
            Bound::Setting(name, _) => name.to_string(),
            Bound::Finite => String::new(),
        }
    }
}

macro_rules! bound_from {
    ($($t:ty),*) => {$(
        impl<C> From<$t> for Bound<C> {
            fn from(x: $t) -> Self {
                Bound::Number(x as f64)
            }
        }
    )*};
}
bound_from!(f64, f32, u32, u64);

/// The bound given by a sibling setting, named as in the configuration.
pub fn setting<C>(name: &'static str, value: fn(&C) -> f64) -> Bound<C> {
    Bound::Setting(name, value)
}

/// How one field of a [`settings!`](crate::settings!) structure is documented and checked.
pub struct Spec<C> {
    kind: Kind,
    range: Option<Range<C>>,
    unit: &'static str,
}

struct Range<C> {
    low: Bound<C>,
    /// The low bound itself is out of range.
    open: bool,
    high: Bound<C>,
}

/// A value that is always present (a number, a flag, a named option).
pub fn value<C>() -> Spec<C> {
    Spec {
        kind: Kind::Value,
        range: None,
        unit: "",
    }
}

/// A value that may be unset; `example` is what the printed defaults show
/// for it, commented out.
pub fn optional<C>(example: &'static str) -> Spec<C> {
    Spec {
        kind: Kind::Optional { example },
        ..value()
    }
}

/// A nested settings structure, printed as a `[section]`.
pub fn section<C>() -> Spec<C> {
    Spec {
        kind: Kind::Section,
        ..value()
    }
}

/// One of several variants, its own [`Setting`] documenting and checking
/// them.
pub fn choice<C>() -> Spec<C> {
    Spec {
        kind: Kind::Choice,
        ..value()
    }
}

impl<C> Spec<C> {
    /// Valid from `low` to `high`, both included.
    pub fn range(self, low: impl Into<Bound<C>>, high: impl Into<Bound<C>>) -> Self {
        self.with_range(low.into(), false, high.into())
    }

    /// Valid above `low` (excluded) up to `high` (included).
    pub fn above(self, low: impl Into<Bound<C>>, high: impl Into<Bound<C>>) -> Self {
        self.with_range(low.into(), true, high.into())
    }

    /// Valid above `low` (excluded), any finite value.
    pub fn positive(self) -> Self {
        self.with_range(Bound::Number(0.0), true, Bound::Finite)
    }

    /// Valid from `low` (included), any finite value.
    pub fn at_least(self, low: impl Into<Bound<C>>) -> Self {
        self.with_range(low.into(), false, Bound::Finite)
    }

    /// The unit said after the bounds ("metres").
    pub fn unit(self, unit: &'static str) -> Self {
        Spec { unit, ..self }
    }

    fn with_range(self, low: Bound<C>, open: bool, high: Bound<C>) -> Self {
        Spec {
            range: Some(Range { low, open, high }),
            ..self
        }
    }

    /// What the range allows, with the bounds as given ("from 1 to 1000
    /// metres"): the documented text and the error message say the same.
    fn allows(&self, r: &Range<C>, low: &str, high: &str) -> String {
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        match (r.open, &r.high) {
            (false, Bound::Finite) => format!("at least {low}{unit}"),
            (true, Bound::Finite) => format!("above {low}{unit}"),
            (false, _) => format!("from {low} to {high}{unit}"),
            (true, _) => format!("above {low} and at most {high}{unit}"),
        }
    }

    /// What the range allows, for users ("Integer from 1 to 1000.").
    fn range_text(&self, integer: bool) -> String {
        let Some(r) = &self.range else {
            return String::new();
        };
        let text = self.allows(r, &r.low.text(), &r.high.text());
        if integer {
            format!("Integer {text}.")
        } else {
            let mut c = text.chars();
            let first = c.next().map(|f| f.to_ascii_uppercase());
            format!("{}{}.", first.into_iter().collect::<String>(), c.as_str())
        }
    }

    /// The documentation of field `key` whose rustdoc is `doc`.
    pub fn doc(&self, key: String, doc: &str, integer: bool) -> KeyDoc {
        let mut text = doc.split_whitespace().collect::<Vec<_>>().join(" ");
        let range = self.range_text(integer);
        if !range.is_empty() {
            text = format!("{text} {range}");
        }
        KeyDoc {
            key,
            kind: self.kind,
            text,
        }
    }

    /// Checks `value` of field `key` of `config` against the range.
    pub fn check(&self, key: &str, value: Option<f64>, config: &C) -> Result<(), OutOfRange> {
        let (Some(r), Some(x)) = (&self.range, value) else {
            return Ok(());
        };
        let (low, high) = (r.low.value(config), r.high.value(config));
        let above_low = if r.open { x > low } else { x >= low };
        if above_low && x <= high && x.is_finite() {
            return Ok(());
        }
        let named = |b: &Bound<C>, v: f64| match b {
            Bound::Setting(name, _) => format!("{name} ({v})"),
            _ => display(v),
        };
        let allowed = self.allows(r, &named(&r.low, low), &named(&r.high, high));
        Err(OutOfRange {
            key: key.to_string(),
            reason: format!("{} must be {allowed}", display(x)),
        })
    }
}

/// A number as users wrote it (`NaN`, `inf`, `1e30`).
fn display(x: f64) -> String {
    if x.abs() >= 1e16 {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}

/// `prefix.name`, or `name` at the top.
pub fn join(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

/// Declares a settings structure: each field with its rustdoc (which is
/// also its text for users), type, default and [`Spec`]. Generates the
/// structure (serde, unknown keys refused, missing keys defaulted), its
/// `Default` and its [`Setting`] impl, which documents the fields as a
/// section and checks their ranges.
///
/// ```ignore
/// settings! {
///     /// Keyframe selection.
///     pub struct KeyframeConfig {
///         /// How far the camera must move, metres.
///         pub min_translation: f64 = 0.0 => value().range(0.0, 5000.0),
///     }
/// }
/// ```
#[macro_export]
macro_rules! settings {
    (
        $(#[$attr:meta])*
        pub struct $name:ident {
            $(
                $(#[doc = $doc:literal])*
                pub $field:ident : $ty:ty = $default:expr => $spec:expr
            ),* $(,)?
        }
    ) => {
        $(#[$attr])*
        #[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
        #[serde(default, deny_unknown_fields)]
        pub struct $name {
            $(
                $(#[doc = $doc])*
                pub $field: $ty,
            )*
        }

        impl Default for $name {
            fn default() -> Self {
                $name {
                    $($field: $default,)*
                }
            }
        }

        impl $crate::settings::Setting for $name {
            fn nested_docs(prefix: &str, out: &mut Vec<$crate::settings::KeyDoc>) {
                #[allow(unused_imports)]
                use $crate::settings::{choice, optional, section, setting, value};
                $(
                    let key = $crate::settings::join(prefix, stringify!($field));
                    let spec: $crate::settings::Spec<$name> = $spec;
                    let doc = concat!($($doc, "\n"),*);
                    out.push(spec.doc(
                        key.clone(),
                        doc,
                        <$ty as $crate::settings::Setting>::INTEGER,
                    ));
                    <$ty as $crate::settings::Setting>::nested_docs(&key, out);
                )*
            }

            fn check_nested(
                &self,
                prefix: &str,
            ) -> Result<(), $crate::settings::OutOfRange> {
                #[allow(unused_imports)]
                use $crate::settings::{choice, optional, section, setting, value};
                $(
                    let key = $crate::settings::join(prefix, stringify!($field));
                    let spec: $crate::settings::Spec<$name> = $spec;
                    spec.check(
                        &key,
                        $crate::settings::Setting::number(&self.$field),
                        self,
                    )?;
                    $crate::settings::Setting::check_nested(&self.$field, &key)?;
                )*
                Ok(())
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    settings! {
        /// A test structure.
        pub struct Inner {
            /// A count.
            pub count: u32 = 3 => value().range(1u32, 10u32),
            /// The upper limit of length.
            pub limit: f64 = 2.0 => value().positive(),
            /// A length.
            pub length: f64 = 0.5 => value().above(0.0, setting("limit", |c: &Inner| c.limit)).unit("metres"),
            /// An unset size.
            pub size: Option<u64> = None => optional("7").at_least(1u32),
        }
    }

    settings! {
        /// The top.
        pub struct Outer {
            /// A flag.
            pub flag: bool = false => value(),
            /// The inner section.
            pub inner: Inner = Inner::default() => section(),
        }
    }

    #[test]
    fn ranges_are_documented_and_checked_as_declared() {
        let mut docs = Vec::new();
        Outer::nested_docs("", &mut docs);
        let texts: Vec<(&str, &str)> = docs
            .iter()
            .map(|d| (d.key.as_str(), d.text.as_str()))
            .collect();
        assert_eq!(
            texts,
            [
                ("flag", "A flag."),
                ("inner", "The inner section."),
                ("inner.count", "A count. Integer from 1 to 10."),
                ("inner.limit", "The upper limit of length. Above 0."),
                (
                    "inner.length",
                    "A length. Above 0 and at most limit metres."
                ),
                ("inner.size", "An unset size. Integer at least 1."),
            ]
        );
        assert_eq!(docs[1].kind, Kind::Section);
        assert_eq!(docs[5].kind, Kind::Optional { example: "7" });

        let ok = Outer::default();
        assert_eq!(ok.check_nested(""), Ok(()));
        let with = |f: &dyn Fn(&mut Inner)| {
            let mut o = Outer::default();
            f(&mut o.inner);
            o.check_nested("").unwrap_err().to_string()
        };
        assert_eq!(with(&|i| i.count = 0), "inner.count 0 must be from 1 to 10");
        assert_eq!(
            with(&|i| i.count = 11),
            "inner.count 11 must be from 1 to 10"
        );
        assert_eq!(
            with(&|i| i.length = 3.0),
            "inner.length 3 must be above 0 and at most limit (2) metres"
        );
        assert_eq!(
            with(&|i| i.length = 0.0),
            "inner.length 0 must be above 0 and at most limit (2) metres"
        );
        assert_eq!(
            with(&|i| i.limit = f64::NAN),
            "inner.limit NaN must be above 0"
        );
        assert_eq!(
            with(&|i| i.limit = f64::INFINITY),
            "inner.limit inf must be above 0"
        );
        assert_eq!(
            with(&|i| i.size = Some(0)),
            "inner.size 0 must be at least 1"
        );
        let mut o = Outer::default();
        o.inner.size = Some(5);
        o.inner.length = 2.0;
        assert_eq!(o.check_nested(""), Ok(()));
    }
}
