//! Access to [`Settings`] by node path (`/sample/youngs_modulus`): `Settings::get`, `set`,
//! `apply`, `nodes`, and [`NodeInfo`], the protocol's `list` entry with each node's bounds
//! as they stand now. The nodes themselves are the node table (`field`), listed by the
//! registry ([`registry`]).

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::error::NodeError;
use super::field::Field;
use super::kind::Kind;
use super::limits::MAX_YOUNGS_MODULUS;
use super::range::Bound;
use super::registry::{self, node, registry};
use super::relations;
use super::settings::Settings;
use super::show::show_json;
use super::spec::NodeSpec;

impl NodeSpec {
    /// The lowest and highest value `set` would accept now, as the protocol's `list` reports
    /// them: the static range narrowed by the limits that depend on other nodes; `null` for
    /// text, lists of text and bool. Whether each end is itself allowed:
    /// [`Self::bounds_and_ends`].
    pub(crate) fn bounds(&self, s: &Settings) -> (Value, Value) {
        let (min, max, _) = self.bounds_and_ends(s);
        (min, max)
    }

    /// [`Self::bounds`], and whether the lowest and the highest value are themselves
    /// allowed (`0 < value` excludes its 0); `None` where the node has no bounds.
    fn bounds_and_ends(&self, s: &Settings) -> (Value, Value, Option<(bool, bool)>) {
        let sample_rate = s.synth.sample_rate;
        match self.kind {
            Kind::Float(range) | Kind::FloatList { entry: range, .. } => {
                let (mut low, mut high) = (range.min, range.max);
                // A limit from another node replaces an end it lies inside of, or excludes
                // an end it shares.
                let mut below = |value: f64, inclusive: bool| {
                    if value < high.value || (value == high.value && !inclusive) {
                        high = Bound { value, inclusive };
                    }
                };
                // The lower limits from other nodes all allow their end.
                let mut above = |value: f64| {
                    if value > low.value {
                        low = Bound {
                            value,
                            inclusive: true,
                        };
                    }
                };
                match self.field {
                    Field::DriveFrequency | Field::CantileverF1
                        if self.field == Field::DriveFrequency || s.drive.follow_f1 =>
                    {
                        // The Nyquist frequency itself is excluded.
                        below(relations::highest_drive_frequency(s), false);
                        above(relations::lowest_drive_frequency(s));
                    }
                    // While it drives, the second excitation stays below Nyquist.
                    Field::Drive2Frequency if s.drive2.enable => below(sample_rate / 2.0, false),
                    Field::DemodTimeconstant(_) => above(1.0 / sample_rate),
                    Field::DemodRate(_) | Field::SpectrumRate => below(sample_rate, true),
                    Field::ScopeRate => below(relations::highest_scope_rate(s), true),
                    // An inclusion given relative to the base material must stay a modulus.
                    Field::InclusionRelativeModulus(_) => {
                        below(MAX_YOUNGS_MODULUS / s.sample.youngs_modulus, true);
                    }
                    Field::SampleYoungsModulus => {
                        let most = s
                            .inclusions
                            .iter()
                            .map(|i| i.relative_modulus)
                            .fold(0.0, f64::max);
                        if most > 0.0 {
                            below(MAX_YOUNGS_MODULUS / most, true);
                        }
                    }
                    Field::ScanLineRate => below(relations::highest_line_rate(s), true),
                    _ => {}
                }
                (
                    Value::from(low.value),
                    Value::from(high.value),
                    Some((low.inclusive, high.inclusive)),
                )
            }
            Kind::Integer { mut min, mut max } => {
                let enabled = |i: usize| s.demods.get(i).is_some_and(|d| d.enable);
                match self.field {
                    // The inversion's harmonic is measured by this one alone.
                    Field::DemodHarmonic(i)
                        if enabled(i) && relations::sole_inversion_measure(s, i) =>
                    {
                        (min, max) = (
                            u64::from(s.demods[i].harmonic),
                            u64::from(s.demods[i].harmonic),
                        );
                    }
                    Field::InversionHarmonicA | Field::InversionHarmonicB => {
                        let other = if self.field == Field::InversionHarmonicA {
                            s.inversion.harmonic_b
                        } else {
                            s.inversion.harmonic_a
                        };
                        if let Some((low, high)) = relations::inversion_harmonic_bounds(s, other) {
                            (min, max) = (low, high);
                        }
                    }
                    Field::ScopeLength => {
                        max = max.min(
                            relations::longest_scope_span(s) / u64::from(s.scope.decimation).max(1),
                        );
                    }
                    Field::ScopeDecimation => {
                        max = max.min(
                            relations::longest_scope_span(s) / u64::from(s.scope.length).max(1),
                        );
                    }
                    Field::ScanPixels => max = max.min(relations::highest_scan_pixels(s)),
                    Field::CantileverExtraModes => max = max.min(relations::most_extra_modes(s)),
                    _ => {}
                }
                (Value::from(min), Value::from(max), Some((true, true)))
            }
            Kind::PowerOfTwo { min, max } | Kind::Even { min, max } => {
                (Value::from(min), Value::from(max), Some((true, true)))
            }
            Kind::Bool | Kind::Text(_) | Kind::TextList { .. } => (Value::Null, Value::Null, None),
        }
    }
}

/// One entry of the protocol's `list` reply: a node with its current value.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeInfo {
    /// The node path.
    pub path: String,
    /// Current value (number, integer, bool, string, or list of numbers or of strings).
    pub value: Value,
    /// SI unit; `1` for dimensionless, empty for text, bool and the inversion's harmonic
    /// numbers.
    pub unit: String,
    /// Whether `set` may change it at runtime.
    pub writable: bool,
    /// Lowest value accepted now (an end that is itself excluded, like the 0 of `0 < value`,
    /// is still reported: see `min_inclusive`), or `null` (text, booleans, lists of text).
    /// For a list of numbers, the bound of each entry.
    pub min: Value,
    /// Highest value accepted now, or `null`. For a list, the bound of each entry.
    pub max: Value,
    /// Whether `min` itself is accepted (`false` for the 0 of `0 < value`); absent where
    /// `min` is `null`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_inclusive: Option<bool>,
    /// Whether `max` itself is accepted (`false` for the Nyquist frequency of
    /// `/drive/frequency`); absent where `max` is `null`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_inclusive: Option<bool>,
    /// One sentence with the unit.
    pub description: String,
    /// The value's type: `"float"`, `"integer"` (a power of two where `description` says
    /// so), `"bool"`, `"text"`, `"float_list"` or `"text_list"`.
    #[serde(rename = "type")]
    pub kind: String,
    /// For a text node, the values it accepts; absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub allowed: Option<Vec<String>>,
    /// What the current value means for the instrument when it is not what the node alone
    /// suggests (e.g. a demodulator out of band); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
}

/// Whether a `set` comes over the protocol (read-only nodes refused) or from a config file.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Access {
    Runtime,
    ConfigFile,
}

impl Settings {
    /// The current value of the node at `path`, as the protocol's `get` returns it.
    pub fn get(&self, path: &str) -> Result<Value, NodeError> {
        let unknown = || NodeError::UnknownPath {
            path: path.to_owned(),
        };
        let spec = node(path).ok_or_else(unknown)?;
        spec.field
            .read(self)
            .map(|v| v.to_json())
            .ok_or_else(unknown)
    }

    /// The protocol's `set`: changes one node and returns the value as applied (e.g. `4.0`
    /// for an integer node comes back as `4`). Read-only nodes give [`NodeError::ReadOnly`].
    /// Transactional: the value is checked on its own, then applied to a copy that must pass
    /// [`Settings::validate`]; on any error `self` is unchanged.
    pub fn set(&mut self, path: &str, value: &Value) -> Result<Value, NodeError> {
        self.assign(path, value, Access::Runtime)
    }

    /// The protocol's batch `set`: changes every node of `values` together and returns each
    /// value as applied, in order. The nodes are written first and checked against each
    /// other once, so a batch may move two nodes that constrain each other (a harmonic and
    /// the drive frequency) where either `set` alone would be refused. Read-only nodes give
    /// [`NodeError::ReadOnly`]; on any error, which names its node, `self` is unchanged.
    pub fn set_many(&mut self, values: &[(String, Value)]) -> Result<Vec<Value>, NodeError> {
        let mut next = self.clone();
        for (path, value) in values {
            let spec = node(path).ok_or_else(|| NodeError::UnknownPath { path: path.clone() })?;
            if !spec.writable {
                return Err(NodeError::ReadOnly { path: path.clone() });
            }
            next.write_node(spec, value)?;
        }
        let written: Vec<&str> = values.iter().map(|(p, _)| p.as_str()).collect();
        next.derive_linked(&written)?;
        next.validate()?;
        let applied = values
            .iter()
            .map(|(path, _)| next.get(path))
            .collect::<Result<Vec<_>, _>>()?;
        *self = next;
        Ok(applied)
    }

    /// Like [`Settings::set`], but also for nodes that are read-only at runtime (as a config
    /// file may set them). Use it to build settings that take effect at the next start.
    pub fn apply(&mut self, path: &str, value: &Value) -> Result<Value, NodeError> {
        self.assign(path, value, Access::ConfigFile)
    }

    fn assign(&mut self, path: &str, value: &Value, access: Access) -> Result<Value, NodeError> {
        let spec = node(path).ok_or_else(|| NodeError::UnknownPath {
            path: path.to_owned(),
        })?;
        if access == Access::Runtime && !spec.writable {
            return Err(NodeError::ReadOnly {
                path: path.to_owned(),
            });
        }
        let mut next = self.clone();
        next.write_node(spec, value)?;
        next.derive_linked(&[path])?;
        next.validate().map_err(|error| match error {
            // A conflict found on another node: report it as this `set`'s failure, naming
            // the value tried and the node it conflicts with.
            NodeError::InvalidValue {
                path: other,
                message,
            } if other != path => NodeError::InvalidValue {
                path: path.to_owned(),
                message: format!("cannot set {path} = {}: {message}", show_json(value)),
            },
            error => error,
        })?;
        let applied = next.get(path)?;
        *self = next;
        Ok(applied)
    }

    /// The nodes that follow others, after the nodes at `written` were written together (one
    /// `set`, or a whole config file): the drive on f1 ([`Settings::follow_f1`]) and each
    /// inclusion's modulus on the base material's ([`Settings::follow_sample`]).
    pub(crate) fn derive_linked(&mut self, written: &[&str]) -> Result<(), NodeError> {
        self.follow_f1(written)?;
        self.follow_sample(written)
    }

    /// Keeps each inclusion's `youngs_modulus` at `relative_modulus` × the base material's
    /// while `relative_modulus` > 0, after the nodes at `written` were written together: an
    /// absolute modulus given without `relative_modulus` makes the inclusion absolute;
    /// giving both a relative modulus > 0 and another absolute one is a conflict.
    fn follow_sample(&mut self, written: &[&str]) -> Result<(), NodeError> {
        let base = self.sample.youngs_modulus;
        for (i, inclusion) in self.inclusions.iter_mut().enumerate() {
            let absolute = format!("/inclusions/{i}/youngs_modulus");
            let gave_absolute = written.contains(&absolute.as_str());
            let gave_relative =
                written.contains(&format!("/inclusions/{i}/relative_modulus").as_str());
            let derived = inclusion.relative_modulus * base;
            if gave_absolute && !gave_relative && inclusion.youngs_modulus != derived {
                inclusion.relative_modulus = 0.0;
            }
            if inclusion.relative_modulus > 0.0 {
                let derived = inclusion.relative_modulus * base;
                if gave_absolute && inclusion.youngs_modulus != derived {
                    return Err(NodeError::InvalidValue {
                        path: absolute.clone(),
                        message: format!(
                            "{absolute} = {} conflicts with /inclusions/{i}/relative_modulus = \
                             {}, which makes it {} × /sample/youngs_modulus = {}: give \
                             /inclusions/{i}/relative_modulus = 0 for an absolute modulus, or \
                             leave {absolute} out",
                            super::quantity::quantity(inclusion.youngs_modulus, "Pa"),
                            inclusion.relative_modulus,
                            inclusion.relative_modulus,
                            super::quantity::quantity(derived, "Pa")
                        ),
                    });
                }
                inclusion.youngs_modulus = derived;
            }
        }
        Ok(())
    }

    /// Keeps `/drive/frequency` on `/cantilever/f1` while `/drive/follow_f1` is true, after
    /// the nodes at `written` were written together (one `set`, or a whole config file), so
    /// the order of keys never matters: a drive frequency other than f1 given without
    /// `follow_f1` turns following off (the drive was set explicitly); while following, the
    /// drive frequency is f1.
    /// Giving both a drive frequency other than f1 and `follow_f1 = true` is a conflict.
    fn follow_f1(&mut self, written: &[&str]) -> Result<(), NodeError> {
        let gave = |p: &str| written.contains(&p);
        let (frequency, follow) = ("/drive/frequency", "/drive/follow_f1");
        if gave(frequency) && !gave(follow) && self.drive.frequency != self.cantilever.f1 {
            self.drive.follow_f1 = false;
        }
        if self.drive.follow_f1 {
            if gave(frequency) && self.drive.frequency != self.cantilever.f1 {
                return Err(NodeError::InvalidValue {
                    path: frequency.to_owned(),
                    message: format!(
                        "/drive/frequency = {} conflicts with /drive/follow_f1 = true, which \
                         keeps the drive at /cantilever/f1 = {}: give /drive/follow_f1 = false \
                         to drive off resonance, or leave /drive/frequency out",
                        super::quantity::quantity(self.drive.frequency, "Hz"),
                        super::quantity::quantity(self.cantilever.f1, "Hz")
                    ),
                });
            }
            self.drive.frequency = self.cantilever.f1;
        }
        Ok(())
    }

    /// Checks `value` against the node's own type and range and stores it, without the
    /// checks between nodes (the config loader runs those once, after the whole file).
    pub(crate) fn write_node(&mut self, spec: &NodeSpec, value: &Value) -> Result<(), NodeError> {
        let typed = spec.parse(value)?;
        spec.field
            .write(self, typed)
            .ok_or_else(|| NodeError::UnknownPath {
                path: spec.path.clone(),
            })
    }

    /// Every node with its current value, in tree order: the protocol's `list`.
    pub fn nodes(&self) -> Vec<NodeInfo> {
        self.nodes_under("")
    }

    /// The protocol's `list`: the nodes at or below `prefix` ([`Settings::nodes_under`]), or
    /// [`NodeError::UnknownPath`] for a malformed path (the rule of `get` and `set`: no
    /// `//`, no trailing `/`) or one with no node at or below it.
    pub fn list(&self, prefix: &str) -> Result<Vec<NodeInfo>, NodeError> {
        let nodes = self.nodes_under(prefix);
        if nodes.is_empty() {
            let path = prefix.to_owned();
            return Err(if registry::well_formed(prefix) {
                NodeError::NothingUnder { path }
            } else {
                NodeError::UnknownPath { path }
            });
        }
        Ok(nodes)
    }

    /// The nodes at or below `prefix`, matched by whole path segments: `/demods/1` lists
    /// `/demods/1/…` but not `/demods/10/…`. An empty prefix or `/` lists every node; a
    /// malformed prefix (`//`, `/demods/`) lists none.
    pub fn nodes_under(&self, prefix: &str) -> Vec<NodeInfo> {
        let whole_tree = prefix.is_empty() || prefix == "/";
        if !whole_tree && !registry::well_formed(prefix) {
            return Vec::new();
        }
        let prefix = if whole_tree { "" } else { prefix };
        registry()
            .iter()
            .filter(|spec| {
                prefix.is_empty()
                    || spec.path == prefix
                    || spec
                        .path
                        .strip_prefix(prefix)
                        .is_some_and(|rest| rest.starts_with('/'))
            })
            .filter_map(|spec| {
                let value = spec.field.read(self)?.to_json();
                let (min, max, ends) = spec.bounds_and_ends(self);
                Some(NodeInfo {
                    path: spec.path.clone(),
                    value,
                    unit: spec.unit.to_owned(),
                    writable: spec.writable,
                    min,
                    max,
                    min_inclusive: ends.map(|e| e.0),
                    max_inclusive: ends.map(|e| e.1),
                    description: spec.description.clone(),
                    kind: spec.kind.type_name().to_owned(),
                    allowed: match spec.kind {
                        Kind::Text(choices) => {
                            Some(choices.iter().map(|c| (*c).to_owned()).collect())
                        }
                        _ => None,
                    },
                    warning: self.node_warning(&spec.path),
                })
            })
            .collect()
    }
}
