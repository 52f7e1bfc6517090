//! The checks of one value against its node on its own ([`NodeSpec::parse`],
//! [`NodeSpec::check`]): type, range, list lengths, text entries. Limits between nodes are
//! in `relations`.

use serde_json::Value;

use super::error::NodeError;
use super::kind::{Kind, TextEntry, Typed};
use super::quantity::number;
use super::show::show_json;
use super::spec::NodeSpec;

impl NodeSpec {
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
}
