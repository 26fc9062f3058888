//! Settings structs declared once: each setting's name, default, bounds, unit, audience and
//! description in one line of a [`settings_struct!`] block, from which the struct, its
//! `Default`, its validating `from_map` and the schema the Python side builds its pydantic model
//! from (`soilocp._core.settings_schema`) all follow.

use std::collections::HashMap;

/// Who a setting is for.  A user setting is documented (what it does, its unit, when to change
/// it); an internal one is a constant of the method, named here with the reason for its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Audience {
    User,
    Internal,
}

/// The type of a setting's value: numbers travel as f64 (an `Int` must be a whole number); a
/// `Choice` is one of a fixed list of names (its field is that `&'static str`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Float,
    Int,
    Choice,
}

/// A value as given for a setting: a number, or the name of a choice.
pub trait Given {
    fn number(&self) -> Option<f64>;
    fn name(&self) -> Option<&str>;
}

impl Given for f64 {
    fn number(&self) -> Option<f64> {
        Some(*self)
    }

    fn name(&self) -> Option<&str> {
        None
    }
}

/// A setting's value as Python gives it: a number, or a choice's name.
#[derive(Clone, Debug, PartialEq, pyo3::FromPyObject)]
pub enum Value {
    Number(f64),
    Name(String),
}

impl Given for Value {
    fn number(&self) -> Option<f64> {
        match self {
            Value::Number(v) => Some(*v),
            Value::Name(_) => None,
        }
    }

    fn name(&self) -> Option<&str> {
        match self {
            Value::Number(_) => None,
            Value::Name(n) => Some(n),
        }
    }
}

/// The index of `v` in `choices` (a const fn: a choice setting whose default is not one of its
/// choices does not compile).
pub const fn choice_index(choices: &[&str], v: &str) -> usize {
    let mut i = 0;
    while i < choices.len() {
        let (a, b) = (choices[i].as_bytes(), v.as_bytes());
        if a.len() == b.len() {
            let mut j = 0;
            while j < a.len() && a[j] == b[j] {
                j += 1;
            }
            if j == a.len() {
                return i;
            }
        }
        i += 1;
    }
    panic!("a choice setting's default must be one of its choices");
}

/// A setting's bounds, in pydantic's words (`gt`, `ge`, `lt`, `le`); `None`: no bound.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub gt: Option<f64>,
    pub ge: Option<f64>,
    pub lt: Option<f64>,
    pub le: Option<f64>,
}

impl Bounds {
    /// No bound.
    pub const NONE: Bounds = Bounds {
        gt: None,
        ge: None,
        lt: None,
        le: None,
    };

    pub const fn gt(self, v: f64) -> Bounds {
        Bounds { gt: Some(v), ..self }
    }

    pub const fn ge(self, v: f64) -> Bounds {
        Bounds { ge: Some(v), ..self }
    }

    pub const fn lt(self, v: f64) -> Bounds {
        Bounds { lt: Some(v), ..self }
    }

    pub const fn le(self, v: f64) -> Bounds {
        Bounds { le: Some(v), ..self }
    }

    /// The first bound `v` violates, worded ("> 0"), or None.
    pub fn violated(&self, v: f64) -> Option<String> {
        let checks = [
            (self.gt, ">", v > self.gt.unwrap_or(f64::NEG_INFINITY)),
            (self.ge, ">=", v >= self.ge.unwrap_or(f64::NEG_INFINITY)),
            (self.lt, "<", v < self.lt.unwrap_or(f64::INFINITY)),
            (self.le, "<=", v <= self.le.unwrap_or(f64::INFINITY)),
        ];
        checks
            .iter()
            .find(|(b, _, ok)| b.is_some() && !ok)
            .map(|(b, op, _)| format!("{op} {}", b.unwrap_or_default()))
    }
}

/// One setting, as declared.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spec {
    pub name: &'static str,
    pub kind: Kind,
    /// the default (a `Choice`'s: the index of its default in `choices`)
    pub default: f64,
    /// a `Choice`'s allowed names (empty for a number)
    pub choices: &'static [&'static str],
    pub bounds: Bounds,
    /// the unit ("" for a number without one)
    pub unit: &'static str,
    pub audience: Audience,
    /// what it does and when to change it (a user setting), or why it has its value (internal)
    pub doc: &'static str,
}

impl Spec {
    /// `v` if it is a valid value of this setting, else the error naming it.
    pub fn check(&self, group: &str, v: f64) -> Result<f64, String> {
        if !v.is_finite() {
            return Err(format!("{group} settings: {} = {v} must be finite", self.name));
        }
        if self.kind == Kind::Int && v.fract() != 0.0 {
            return Err(format!("{group} settings: {} = {v} must be a whole number", self.name));
        }
        match self.bounds.violated(v) {
            Some(need) => Err(format!("{group} settings: {} = {v} must be {need}", self.name)),
            None => Ok(v),
        }
    }

    /// The value of this setting given as `g`: a number checked as [`Spec::check`] does, or a
    /// choice's index (as f64); the error names the setting.
    pub fn take<G: Given + ?Sized>(&self, group: &str, g: &G) -> Result<f64, String> {
        if self.kind != Kind::Choice {
            return match g.number() {
                Some(v) => self.check(group, v),
                None => Err(format!("{group} settings: {} must be a number", self.name)),
            };
        }
        let name = g.name();
        match name.and_then(|n| self.choices.iter().position(|c| *c == n)) {
            Some(i) => Ok(i as f64),
            None => Err(format!(
                "{group} settings: {} = {} must be one of {}",
                self.name,
                name.map_or_else(|| "a number".to_string(), |n| format!("{n:?}")),
                self.choices.join(", ")
            )),
        }
    }
}

/// The values of `specs`, in order, from a name -> value map: a name not in `specs` is refused
/// (the error names it and the valid names), a missing one takes its default, each value is
/// checked against its bounds (a choice's: its index, see [`Spec::take`]).
pub fn values<G: Given>(group: &str, specs: &[Spec], m: &HashMap<String, G>) -> Result<Vec<f64>, String> {
    if let Some(k) = m.keys().find(|k| !specs.iter().any(|s| s.name == k.as_str())) {
        let valid: Vec<&str> = specs.iter().map(|s| s.name).collect();
        return Err(format!(
            "{group} settings: unknown setting {k:?} (valid: {})",
            valid.join(", ")
        ));
    }
    specs
        .iter()
        .map(|s| match m.get(s.name) {
            Some(g) => s.take(group, g),
            None if s.kind == Kind::Choice => Ok(s.default),
            None => s.check(group, s.default),
        })
        .collect()
}

/// The Rust type of a setting's field.
macro_rules! setting_type {
    (Choice) => { &'static str };
    ($kind:ident) => { f64 };
}

/// A declaration's [`Spec`]; a `Choice`'s list is `[one_of "a", one_of "b", ...]`, its default
/// one of them.
macro_rules! setting_spec {
    ($field:ident, Choice, $default:expr, $audience:ident, $unit:literal, [$(one_of $value:literal),+], $doc:expr) => {
        $crate::settings::Spec {
            name: stringify!($field),
            kind: $crate::settings::Kind::Choice,
            default: $crate::settings::choice_index(&[$($value),+], $default) as f64,
            choices: &[$($value),+],
            bounds: $crate::settings::Bounds::NONE,
            unit: $unit,
            audience: $crate::settings::Audience::$audience,
            doc: $doc,
        }
    };
    ($field:ident, $kind:ident, $default:expr, $audience:ident, $unit:literal, [$($bound:ident $value:literal),*], $doc:expr) => {
        $crate::settings::Spec {
            name: stringify!($field),
            kind: $crate::settings::Kind::$kind,
            default: $default,
            choices: &[],
            bounds: $crate::settings::Bounds::NONE$(.$bound($value))*,
            unit: $unit,
            audience: $crate::settings::Audience::$audience,
            doc: $doc,
        }
    };
}

/// A field's value from [`values`]' (the value, its spec): a choice's index names the choice.
macro_rules! setting_value {
    (Choice, $v:expr) => {{
        let (i, spec): (f64, &$crate::settings::Spec) = $v;
        spec.choices[i as usize]
    }};
    ($kind:ident, $v:expr) => {
        $v.0
    };
}

/// A settings struct of f64 fields, each declared once:
///
/// ```ignore
/// settings_struct! {
///     /// The struct's doc.
///     pub struct Params("group") {
///         /// What it does, when to change it.
///         name: Float = 0.5, User, "s", [gt 0.0];
///         /// One of a fixed list of names.
///         mode: Choice = "fast", Internal, "", [one_of "fast", one_of "exact"];
///     }
/// }
/// ```
///
/// gives the struct, `SPECS` (the declarations, in order), `Default` (the defaults) and
/// `from_map` (see [`values`]).
macro_rules! settings_struct {
    (
        $(#[$meta:meta])*
        pub struct $name:ident($group:literal) {
            $(
                $(#[doc = $doc:literal])+
                $field:ident: $kind:ident = $default:expr, $audience:ident, $unit:literal,
                    [$($bound:ident $value:literal),*];
            )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq)]
        pub struct $name {
            $(
                $(#[doc = $doc])+
                pub $field: $crate::settings::setting_type!($kind),
            )+
        }

        impl $name {
            /// The settings' group name (in error messages and `soilocp._core.settings_schema`).
            pub const GROUP: &'static str = $group;

            /// Every setting's declaration, in the order of the struct.
            pub const SPECS: &'static [$crate::settings::Spec] = &[
                $(
                    $crate::settings::setting_spec!($field, $kind, $default, $audience, $unit,
                                                    [$($bound $value),*], concat!($($doc),+)),
                )+
            ];

            /// From a name -> value map (see crate::settings::values): unknown names refused,
            /// missing ones at their defaults, every value within its bounds.
            pub fn from_map<G: $crate::settings::Given>(
                m: &std::collections::HashMap<String, G>,
            ) -> Result<Self, String> {
                let mut v = $crate::settings::values($group, Self::SPECS, m)?.into_iter().zip(Self::SPECS);
                Ok($name {
                    $($field: $crate::settings::setting_value!(
                        $kind, v.next().expect("one value per declared setting")),)+
                })
            }
        }

        impl Default for $name {
            fn default() -> Self {
                $name {
                    $($field: $default,)+
                }
            }
        }
    };
}

pub(crate) use {setting_spec, setting_type, setting_value, settings_struct};

#[cfg(test)]
mod tests {
    use super::*;

    settings_struct! {
        /// Two settings for the tests.
        pub struct Demo("demo") {
            /// A length.
            length: Float = 0.5, User, "m", [gt 0.0, le 2.0];
            /// A count.
            count: Int = 3.0, Internal, "", [ge 1.0];
            /// A mode.
            mode: Choice = "fast", Internal, "", [one_of "exact", one_of "fast"];
        }
    }

    #[test]
    fn a_choice_is_one_of_its_names() {
        assert_eq!(Demo::default().mode, "fast");
        assert_eq!(Demo::SPECS[2].default, 1.0);
        assert_eq!(Demo::SPECS[2].choices, ["exact", "fast"]);
        let m: HashMap<String, Value> = [
            ("mode".to_string(), Value::Name("exact".into())),
            ("count".into(), Value::Number(2.0)),
        ]
        .into();
        let d = Demo::from_map(&m).unwrap();
        assert_eq!((d.mode, d.count), ("exact", 2.0));
        let bad = |v: Value| Demo::from_map(&[("mode".to_string(), v)].into()).unwrap_err();
        let e = bad(Value::Name("slow".into()));
        assert!(e.contains("mode = \"slow\" must be one of exact, fast"), "{e}");
        assert!(bad(Value::Number(1.0)).contains("mode = a number must be one of"));
        let e = Demo::from_map(&[("count".to_string(), Value::Name("x".into()))].into()).unwrap_err();
        assert!(e.contains("count must be a number"), "{e}");
    }

    #[test]
    fn defaults_specs_and_map_agree() {
        let d = Demo::default();
        assert_eq!((d.length, d.count), (0.5, 3.0));
        assert_eq!(Demo::from_map(&HashMap::<String, f64>::new()).unwrap(), d);
        assert_eq!((Demo::GROUP, Demo::SPECS[0].name), ("demo", "length"));
        assert_eq!(Demo::SPECS[0].doc.trim(), "A length.");
        assert_eq!(Demo::SPECS[1].audience, Audience::Internal);
        let m: HashMap<String, f64> = [("count".to_string(), 7.0)].into();
        assert_eq!(Demo::from_map(&m).unwrap().count, 7.0);
    }

    #[test]
    fn a_bad_value_or_name_is_named() {
        let bad = |k: &str, v: f64| Demo::from_map(&[(k.to_string(), v)].into()).unwrap_err();
        assert!(bad("length", 0.0).contains("length = 0 must be > 0"));
        assert!(bad("length", 2.5).contains("must be <= 2"));
        assert!(bad("length", f64::NAN).contains("finite"));
        assert!(bad("count", 1.5).contains("whole number"));
        let e = bad("lenght", 1.0);
        assert!(
            e.contains("\"lenght\"") && e.contains("valid: length, count, mode"),
            "{e}"
        );
    }
}
