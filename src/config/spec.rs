//! A node with everything static about it ([`NodeSpec`]): a row of the node table as the
//! registry holds it, and what it allows, as messages say it. The checks of a value against
//! it are in `check`.

use super::field::Field;
use super::kind::Kind;

/// One row of the registry: a node and everything static about it.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeSpec {
    /// The node path, e.g. `/sample/youngs_modulus`.
    pub path: String,
    /// Which setting it is.
    pub field: Field,
    /// SI unit (see [`Field::unit`]).
    pub unit: &'static str,
    /// Whether `set` may change it at runtime (config files may always set it).
    pub writable: bool,
    /// Allowed values, without the limits that depend on other nodes.
    pub kind: Kind,
    /// One sentence with the unit.
    pub description: String,
}

impl NodeSpec {
    pub(crate) fn new(field: Field) -> NodeSpec {
        NodeSpec {
            path: field.path(),
            field,
            unit: field.unit(),
            writable: field.writable(),
            kind: field.kind(),
            description: field.description(),
        }
    }

    /// `" Hz"` for a unit that reads after a number, nothing for `1` and text.
    pub(crate) fn unit_suffix(&self) -> String {
        match self.unit {
            "" | "1" => String::new(),
            unit => format!(" {unit}"),
        }
    }

    /// What is allowed, for "is out of range: allowed …".
    pub fn allowed(&self) -> String {
        match self.kind {
            Kind::Float(range) => format!("{range}{}", self.unit_suffix()),
            Kind::Integer { min, max } => format!("{min} ≤ value ≤ {max}"),
            Kind::PowerOfTwo { min, max } => format!("a power of two from {min} to {max}"),
            Kind::Even { min, max } => format!("an even number from {min} to {max}"),
            Kind::Bool => "true or false".to_owned(),
            Kind::Text(choices) => {
                let quoted: Vec<String> = choices.iter().map(|c| format!("{c:?}")).collect();
                format!("one of {}", quoted.join(", "))
            }
            Kind::FloatList { entry, max_len } => format!(
                "a list of 1 to {max_len} numbers, each {entry}{}",
                self.unit_suffix()
            ),
            Kind::TextList {
                max_len,
                max_bytes,
                entry,
            } => format!(
                "a list of 0 to {max_len} strings of at most {max_bytes} bytes, each {}",
                entry.describe()
            ),
        }
    }

    /// What type is expected, for "has the wrong type: expected …".
    pub(crate) fn expected(&self) -> String {
        match self.kind {
            Kind::Float(_) => format!("a number, {}", self.allowed()),
            Kind::Integer { .. } | Kind::PowerOfTwo { .. } | Kind::Even { .. } => {
                format!("an integer, {}", self.allowed())
            }
            Kind::Bool | Kind::Text(_) | Kind::FloatList { .. } | Kind::TextList { .. } => {
                self.allowed()
            }
        }
    }
}
