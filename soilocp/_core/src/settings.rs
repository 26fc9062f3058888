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

/// The type of a setting's value (all travel as f64; an `Int` must be a whole number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Float,
    Int,
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
    pub default: f64,
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
}

/// The values of `specs`, in order, from a name -> value map: a name not in `specs` is refused
/// (the error names it and the valid names), a missing one takes its default, each value is
/// checked against its bounds.
pub fn values(group: &str, specs: &[Spec], m: &HashMap<String, f64>) -> Result<Vec<f64>, String> {
    if let Some(k) = m.keys().find(|k| !specs.iter().any(|s| s.name == k.as_str())) {
        let valid: Vec<&str> = specs.iter().map(|s| s.name).collect();
        return Err(format!(
            "{group} settings: unknown setting {k:?} (valid: {})",
            valid.join(", ")
        ));
    }
    specs
        .iter()
        .map(|s| s.check(group, m.get(s.name).copied().unwrap_or(s.default)))
        .collect()
}

/// A settings struct of f64 fields, each declared once:
///
/// ```ignore
/// settings_struct! {
///     /// The struct's doc.
///     pub struct Params("group") {
///         /// What it does, when to change it.
///         name: Float = 0.5, User, "s", [gt 0.0];
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
                $field:ident: $kind:ident = $default:literal, $audience:ident, $unit:literal,
                    [$($bound:ident $value:literal),*];
            )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq)]
        pub struct $name {
            $(
                $(#[doc = $doc])+
                pub $field: f64,
            )+
        }

        impl $name {
            /// The settings' group name (in error messages and `soilocp._core.settings_schema`).
            pub const GROUP: &'static str = $group;

            /// Every setting's declaration, in the order of the struct.
            pub const SPECS: &'static [$crate::settings::Spec] = &[
                $(
                    $crate::settings::Spec {
                        name: stringify!($field),
                        kind: $crate::settings::Kind::$kind,
                        default: $default,
                        bounds: $crate::settings::Bounds::NONE$(.$bound($value))*,
                        unit: $unit,
                        audience: $crate::settings::Audience::$audience,
                        doc: concat!($($doc),+),
                    },
                )+
            ];

            /// From a name -> value map (see crate::settings::values): unknown names refused,
            /// missing ones at their defaults, every value within its bounds.
            pub fn from_map(m: &std::collections::HashMap<String, f64>) -> Result<Self, String> {
                let mut v = $crate::settings::values($group, Self::SPECS, m)?.into_iter();
                Ok($name {
                    $($field: v.next().expect("one value per declared setting"),)+
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

pub(crate) use settings_struct;

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
        }
    }

    #[test]
    fn defaults_specs_and_map_agree() {
        let d = Demo::default();
        assert_eq!((d.length, d.count), (0.5, 3.0));
        assert_eq!(Demo::from_map(&HashMap::new()).unwrap(), d);
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
        assert!(e.contains("\"lenght\"") && e.contains("valid: length, count"), "{e}");
    }
}
