//! Access to [`Settings`] by node path (`/sample/youngs_modulus`): [`NodeSpec`], a node with
//! its unit, range and description, and the checks of one value against it; [`NodeInfo`], the
//! protocol's `list` entry; and `Settings::get`, `set`, `apply`, `nodes`. The list of nodes
//! itself is the registry ([`registry`]); the config loader, the protocol and the docs test
//! all read it.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::error::{NodeError, cut};
use super::field::{Field, Kind, MAX_YOUNGS_MODULUS, TextEntry, Typed};
use super::quantity::number;
use super::registry::{self, node, registry};
use super::relations;
use super::settings::Settings;

/// A JSON value as a message shows it: numbers compact, anything long cut short.
pub(crate) fn show_json(value: &Value) -> String {
    let text = match value.as_f64() {
        Some(x) if value.is_f64() => number(x),
        _ => value.to_string(),
    };
    cut(&text).into_owned()
}

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
    fn unit_suffix(&self) -> String {
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
    fn expected(&self) -> String {
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

    fn invalid(&self, message: String) -> NodeError {
        NodeError::InvalidValue {
            path: self.path.clone(),
            message,
        }
    }

    fn wrong_type(&self, value: &Value) -> NodeError {
        self.invalid(format!(
            "{} = {} has the wrong type: expected {}",
            self.path,
            show_json(value),
            self.expected()
        ))
    }

    fn out_of_range(&self, shown: &str) -> NodeError {
        self.invalid(format!(
            "{} = {shown} is out of range: allowed {}",
            self.path,
            self.allowed()
        ))
    }

    /// A TOML `nan`/`inf` (JSON cannot carry them): `shown` is the value as the file wrote it.
    pub(crate) fn non_finite(&self, shown: &str) -> NodeError {
        self.invalid(format!(
            "{} = {shown} is not a finite number: allowed {}",
            self.path,
            self.allowed()
        ))
    }

    /// Converts a JSON value to the node's type and checks it against the node's own range.
    /// Integers must be integral numbers (`4` or `4.0`, not `4.5` or `"4"`).
    pub(crate) fn parse(&self, value: &Value) -> Result<Typed, NodeError> {
        let typed = match self.kind {
            Kind::Float(_) => Typed::Float(value.as_f64().ok_or_else(|| self.wrong_type(value))?),
            Kind::Integer { .. } | Kind::PowerOfTwo { .. } | Kind::Even { .. } => {
                Typed::Integer(self.parse_integer(value)?)
            }
            Kind::Bool => Typed::Bool(value.as_bool().ok_or_else(|| self.wrong_type(value))?),
            Kind::Text(choices) => {
                let text = value.as_str().ok_or_else(|| self.wrong_type(value))?;
                let choice = choices.iter().find(|c| **c == text).ok_or_else(|| {
                    self.invalid(format!(
                        "{} = {} is not allowed: choose {}",
                        self.path,
                        show_json(value),
                        self.allowed()
                    ))
                })?;
                Typed::Text(choice)
            }
            Kind::FloatList { .. } => {
                let entries = value.as_array().ok_or_else(|| self.wrong_type(value))?;
                let numbers = entries
                    .iter()
                    .enumerate()
                    .map(|(i, entry)| {
                        entry.as_f64().ok_or_else(|| {
                            self.invalid(format!(
                                "{} = {}: entry {i} ({}) is not a number: expected {}",
                                self.path,
                                show_json(value),
                                show_json(entry),
                                self.allowed()
                            ))
                        })
                    })
                    .collect::<Result<Vec<f64>, NodeError>>()?;
                Typed::FloatList(numbers)
            }
            Kind::TextList { .. } => {
                let entries = value.as_array().ok_or_else(|| self.wrong_type(value))?;
                let texts = entries
                    .iter()
                    .enumerate()
                    .map(|(i, entry)| {
                        entry.as_str().map(str::to_owned).ok_or_else(|| {
                            self.invalid(format!(
                                "{} = {}: entry {i} ({}) is not a string: expected {}",
                                self.path,
                                show_json(value),
                                show_json(entry),
                                self.allowed()
                            ))
                        })
                    })
                    .collect::<Result<Vec<String>, NodeError>>()?;
                Typed::TextList(texts)
            }
        };
        self.check(&typed)?;
        Ok(typed)
    }

    fn parse_integer(&self, value: &Value) -> Result<u64, NodeError> {
        if let Some(n) = value.as_u64() {
            return Ok(n);
        }
        let x = value.as_f64().ok_or_else(|| self.wrong_type(value))?;
        // 2^64 as f64; every integral f64 below it converts to u64 exactly.
        const TWO_TO_64: f64 = 18_446_744_073_709_551_616.0;
        if !(0.0..TWO_TO_64).contains(&x) {
            return Err(self.out_of_range(&show_json(value)));
        }
        if x.fract() != 0.0 {
            return Err(self.invalid(format!(
                "{} = {} is not an integer: allowed {}",
                self.path,
                show_json(value),
                self.allowed()
            )));
        }
        Ok(x as u64)
    }

    /// Checks a typed value against the node's own range (not against other nodes).
    pub(crate) fn check(&self, value: &Typed) -> Result<(), NodeError> {
        match (self.kind, value) {
            (Kind::Float(range), Typed::Float(x)) => {
                if !x.is_finite() {
                    Err(self.non_finite(&value.show()))
                } else if !range.contains(*x) {
                    Err(self.out_of_range(&value.show()))
                } else {
                    Ok(())
                }
            }
            (Kind::Integer { min, max }, Typed::Integer(n)) => {
                if (min..=max).contains(n) {
                    Ok(())
                } else {
                    Err(self.out_of_range(&value.show()))
                }
            }
            (Kind::PowerOfTwo { min, max }, Typed::Integer(n)) => {
                if !(min..=max).contains(n) {
                    Err(self.out_of_range(&value.show()))
                } else if !n.is_power_of_two() {
                    Err(self.invalid(format!(
                        "{} = {n} is not a power of two: allowed {}",
                        self.path,
                        self.allowed()
                    )))
                } else {
                    Ok(())
                }
            }
            (Kind::Even { min, max }, Typed::Integer(n)) => {
                if !(min..=max).contains(n) {
                    Err(self.out_of_range(&value.show()))
                } else if n % 2 != 0 {
                    Err(self.invalid(format!(
                        "{} = {n} is odd: allowed {}",
                        self.path,
                        self.allowed()
                    )))
                } else {
                    Ok(())
                }
            }
            (Kind::Bool, Typed::Bool(_)) => Ok(()),
            (Kind::Text(choices), Typed::Text(text)) if choices.contains(text) => Ok(()),
            (Kind::FloatList { entry, max_len }, Typed::FloatList(list)) => {
                let shown = value.show();
                if list.is_empty() {
                    return Err(self.invalid(format!(
                        "{} = [] is empty: allowed {}",
                        self.path,
                        self.allowed()
                    )));
                }
                if list.len() > max_len {
                    return Err(self.invalid(format!(
                        "{} = {shown} has {} entries: allowed {}",
                        self.path,
                        list.len(),
                        self.allowed()
                    )));
                }
                for (i, x) in list.iter().enumerate() {
                    if !entry.contains(*x) {
                        let problem = if x.is_finite() {
                            "is out of range"
                        } else {
                            "is not a finite number"
                        };
                        return Err(self.invalid(format!(
                            "{} = {shown}: entry {i} ({}) {problem}: allowed {}",
                            self.path,
                            number(*x),
                            self.allowed()
                        )));
                    }
                }
                Ok(())
            }
            (
                Kind::TextList {
                    max_len,
                    max_bytes,
                    entry,
                },
                Typed::TextList(list),
            ) => self.check_texts(value, list, max_len, max_bytes, entry),
            _ => Err(self.invalid(format!(
                "{} = {} has the wrong type: expected {}",
                self.path,
                value.show(),
                self.expected()
            ))),
        }
    }

    /// The entries of a [`Kind::TextList`]: how many, how long, and of what form.
    fn check_texts(
        &self,
        value: &Typed,
        list: &[String],
        max_len: usize,
        max_bytes: usize,
        form: TextEntry,
    ) -> Result<(), NodeError> {
        let shown = value.show();
        if list.len() > max_len {
            return Err(self.invalid(format!(
                "{} = {shown} has {} entries: allowed {}",
                self.path,
                list.len(),
                self.allowed()
            )));
        }
        for (i, text) in list.iter().enumerate() {
            let entry = show_json(&Value::from(text.as_str()));
            let problem = if text.is_empty() {
                "empty".to_owned()
            } else if text.len() > max_bytes {
                format!("{} bytes long", text.len())
            } else if let Some(problem) = form.problem(text) {
                problem.to_owned()
            } else {
                continue;
            };
            return Err(self.invalid(format!(
                "{} = {shown}: entry {i} ({entry}) is {problem}: allowed {}",
                self.path,
                self.allowed()
            )));
        }
        Ok(())
    }

    /// The lowest and highest value `set` would accept now, as the protocol's `list` reports
    /// them: the static range narrowed by the limits that depend on other nodes. Whether an
    /// end itself is allowed is in the docs and in error messages; `null` for text, lists of
    /// text and bool.
    pub(crate) fn bounds(&self, s: &Settings) -> (Value, Value) {
        let sample_rate = s.synth.sample_rate;
        match self.kind {
            Kind::Float(range) | Kind::FloatList { entry: range, .. } => {
                let (mut low, mut high) = (range.min.value, range.max.value);
                match self.field {
                    Field::DriveFrequency | Field::CantileverF1
                        if self.field == Field::DriveFrequency || s.drive.follow_f1 =>
                    {
                        high = high.min(relations::highest_drive_frequency(s));
                        low = low.max(relations::lowest_drive_frequency(s));
                    }
                    Field::DemodTimeconstant(_) => low = low.max(1.0 / sample_rate),
                    Field::DemodRate(_) | Field::SpectrumRate => high = high.min(sample_rate),
                    Field::ScopeRate => high = high.min(relations::highest_scope_rate(s)),
                    // An inclusion given relative to the base material must stay a modulus.
                    Field::InclusionRelativeModulus(_) => {
                        high = high.min(MAX_YOUNGS_MODULUS / s.sample.youngs_modulus);
                    }
                    Field::SampleYoungsModulus => {
                        let most = s
                            .inclusions
                            .iter()
                            .map(|i| i.relative_modulus)
                            .fold(0.0, f64::max);
                        if most > 0.0 {
                            high = high.min(MAX_YOUNGS_MODULUS / most);
                        }
                    }
                    Field::ScanLineRate => high = high.min(relations::highest_line_rate(s)),
                    _ => {}
                }
                (Value::from(low), Value::from(high))
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
                (Value::from(min), Value::from(max))
            }
            Kind::PowerOfTwo { min, max } | Kind::Even { min, max } => {
                (Value::from(min), Value::from(max))
            }
            Kind::Bool | Kind::Text(_) | Kind::TextList { .. } => (Value::Null, Value::Null),
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
    /// is still reported), or `null` (text, booleans, lists of text). For a list of numbers,
    /// the bound of each entry.
    pub min: Value,
    /// Highest value accepted now, or `null`. For a list, the bound of each entry.
    pub max: Value,
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
                let (min, max) = spec.bounds(self);
                Some(NodeInfo {
                    path: spec.path.clone(),
                    value,
                    unit: spec.unit.to_owned(),
                    writable: spec.writable,
                    min,
                    max,
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
