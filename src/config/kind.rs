//! What values a node takes ([`Kind`], [`TextEntry`]) and a value once checked for its type
//! ([`Typed`]), with [`NodeValue`], the conversion between a setting's Rust type and its
//! [`Typed`] form.

use serde_json::Value;

use super::quantity::number;
use super::range::Range;
use super::show::show_json;

/// What values a node takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// A finite number inside the range.
    Float(Range),
    /// An integer with `min ≤ value ≤ max`.
    Integer {
        /// Smallest allowed value.
        min: u64,
        /// Largest allowed value.
        max: u64,
    },
    /// `true` or `false`.
    Bool,
    /// A power of two with `min ≤ value ≤ max` (both powers of two).
    PowerOfTwo {
        /// Smallest allowed value.
        min: u64,
        /// Largest allowed value.
        max: u64,
    },
    /// An even integer with `min ≤ value ≤ max` (both even).
    Even {
        /// Smallest allowed value.
        min: u64,
        /// Largest allowed value.
        max: u64,
    },
    /// One of these strings.
    Text(&'static [&'static str]),
    /// A list of 1 to `max_len` finite numbers, each inside `entry`.
    FloatList {
        /// Range of each entry.
        entry: Range,
        /// Longest list allowed.
        max_len: usize,
    },
    /// A list of 0 to `max_len` strings, each of 1 to `max_bytes` bytes and of the form
    /// `entry` (a JSON array of strings; a TOML array of strings in files).
    TextList {
        /// Longest list allowed.
        max_len: usize,
        /// Longest entry allowed, in bytes (UTF-8).
        max_bytes: usize,
        /// The form every entry takes.
        entry: TextEntry,
    },
}

impl Kind {
    /// The name of the value's type in the protocol's `list` (`type`).
    pub fn type_name(self) -> &'static str {
        match self {
            Kind::Float(_) => "float",
            Kind::Integer { .. } | Kind::PowerOfTwo { .. } | Kind::Even { .. } => "integer",
            Kind::Bool => "bool",
            Kind::Text(_) => "text",
            Kind::FloatList { .. } => "float_list",
            Kind::TextList { .. } => "text_list",
        }
    }
}

/// The form each entry of a [`Kind::TextList`] takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextEntry {
    /// A web origin as browsers send it in the `Origin` header: `http://` or `https://`, then
    /// a non-empty host with an optional `:port`, and nothing after it (no path, not even a
    /// trailing `/`, no query, fragment or user name). A wildcard (`"*"`) is no origin.
    Origin,
    /// A DNS host name as a `Host` header names it, without a port: labels of letters,
    /// digits and `-` separated by dots. No wildcard.
    Host,
}

impl TextEntry {
    /// What an entry looks like, for "allowed …".
    pub fn describe(self) -> &'static str {
        match self {
            TextEntry::Origin => "an origin scheme://host[:port] with scheme http or https",
            TextEntry::Host => "a host name such as lab-pc.example.org, without a port",
        }
    }

    /// Why `entry` is not of this form (a phrase that follows "is"), or `None` if it is.
    /// The length in bytes is checked by the list, not here.
    pub fn problem(self, entry: &str) -> Option<&'static str> {
        match self {
            TextEntry::Origin => origin_problem(entry),
            TextEntry::Host => host_problem(entry),
        }
    }
}

fn host_problem(entry: &str) -> Option<&'static str> {
    if entry.contains('*') {
        return Some(
            "not allowed (wildcards are not supported: a pattern would let names you do not \
             control reach the instrument)",
        );
    }
    if entry.contains(':') {
        return Some("not a host name (no port or scheme: the port never matters here)");
    }
    let label_ok = |l: &str| {
        !l.is_empty()
            && l.len() <= 63
            && !l.starts_with('-')
            && !l.ends_with('-')
            && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
    };
    if !entry.split('.').all(label_ok) {
        return Some(
            "not a host name (labels of letters, digits and \"-\" separated by single dots)",
        );
    }
    None
}

fn origin_problem(entry: &str) -> Option<&'static str> {
    if entry == "*" {
        return Some(
            "not allowed (a wildcard would let any web page drive the instrument; list each \
             origin as scheme://host[:port])",
        );
    }
    let Some(authority) = entry
        .strip_prefix("http://")
        .or_else(|| entry.strip_prefix("https://"))
    else {
        return Some("not an origin (it must start with \"http://\" or \"https://\")");
    };
    if authority.is_empty() {
        return Some("not an origin (the host is missing)");
    }
    if authority.contains('/') {
        return Some(
            "not an origin (it has a path, a \"/\" after the host; an origin is \
             scheme://host[:port], without even a trailing \"/\")",
        );
    }
    if authority.contains(['?', '#']) {
        return Some("not an origin (it has a query or fragment after the host)");
    }
    if authority.contains('@') {
        return Some("not an origin (it has a user name before the host)");
    }
    if authority.contains('*') {
        return Some(
            "not allowed (wildcards are not supported: each entry is one exact origin, and a \
             pattern would let web pages you do not control drive the instrument)",
        );
    }
    if authority
        .chars()
        .any(|c| c.is_whitespace() || c.is_control())
    {
        return Some("not an origin (it contains white space or control characters)");
    }
    // An IPv6 host is bracketed (`[::1]`); otherwise a colon starts the port.
    let (host, port) = if let Some(rest) = authority.strip_prefix('[') {
        let Some((inside, after)) = rest.split_once(']') else {
            return Some("not an origin (the IPv6 host lacks its closing \"]\")");
        };
        if after.is_empty() {
            (inside, None)
        } else if let Some(port) = after.strip_prefix(':') {
            (inside, Some(port))
        } else {
            return Some("not an origin (only \":port\" may follow the IPv6 host)");
        }
    } else {
        match authority.split_once(':') {
            Some((host, port)) => (host, Some(port)),
            None => (authority, None),
        }
    };
    if host.is_empty() {
        return Some("not an origin (the host is missing)");
    }
    if let Some(port) = port {
        let digits = !port.is_empty() && port.bytes().all(|b| b.is_ascii_digit());
        if !digits || port.parse::<u16>().is_err() {
            return Some(
                "not an origin (the port after the host must be a number from 0 to 65535)",
            );
        }
    }
    None
}

/// A node's value once checked for type, in the representation of its [`Kind`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Typed {
    Float(f64),
    Integer(u64),
    Bool(bool),
    Text(&'static str),
    FloatList(Vec<f64>),
    TextList(Vec<String>),
}

impl Typed {
    pub(crate) fn to_json(&self) -> Value {
        match self {
            Typed::Float(x) => Value::from(*x),
            Typed::Integer(n) => Value::from(*n),
            Typed::Bool(b) => Value::from(*b),
            Typed::Text(t) => Value::from(*t),
            Typed::FloatList(list) => Value::from(list.clone()),
            Typed::TextList(list) => Value::from(list.clone()),
        }
    }

    /// The value as a message shows it.
    pub(crate) fn show(&self) -> String {
        match self {
            Typed::Float(x) => number(*x),
            Typed::Integer(n) => n.to_string(),
            Typed::Bool(b) => b.to_string(),
            Typed::Text(t) => format!("{t:?}"),
            Typed::FloatList(list) => {
                // A long list is cut, like any quoted value: its first entries and its length.
                const SHOWN: usize = 16;
                let entries: Vec<String> = list.iter().take(SHOWN).map(|x| number(*x)).collect();
                let more = if list.len() > SHOWN {
                    format!(", … ({} entries)", list.len())
                } else {
                    String::new()
                };
                format!("[{}{more}]", entries.join(", "))
            }
            // Entries may be long and many: shown cut short, like JSON in messages.
            Typed::TextList(_) => show_json(&self.to_json()),
        }
    }
}

/// A setting's Rust type as a node value: how the node table reads a setting into its
/// [`Typed`] form and writes a checked value back.
pub(crate) trait NodeValue: Sized {
    /// The value in the representation of its node's [`Kind`].
    fn typed(&self) -> Typed;
    /// The setting from a value already checked against its node's [`Kind`]; `None` if the
    /// representation does not fit the type (cannot happen after the node's own check).
    fn from_typed(value: Typed) -> Option<Self>;
}

impl NodeValue for f64 {
    fn typed(&self) -> Typed {
        Typed::Float(*self)
    }
    fn from_typed(value: Typed) -> Option<Self> {
        match value {
            Typed::Float(x) => Some(x),
            _ => None,
        }
    }
}

impl NodeValue for bool {
    fn typed(&self) -> Typed {
        Typed::Bool(*self)
    }
    fn from_typed(value: Typed) -> Option<Self> {
        match value {
            Typed::Bool(b) => Some(b),
            _ => None,
        }
    }
}

/// Counts and integers of every width are [`Typed::Integer`]s; a value the width cannot hold
/// never passes the node's range.
macro_rules! integer_value {
    ($($t:ty),*) => {$(
        impl NodeValue for $t {
            fn typed(&self) -> Typed {
                Typed::Integer(u64::try_from(*self).expect("a node's integer fits in u64"))
            }
            fn from_typed(value: Typed) -> Option<Self> {
                match value {
                    Typed::Integer(n) => <$t>::try_from(n).ok(),
                    _ => None,
                }
            }
        }
    )*};
}
integer_value!(u32, u64, usize);

impl NodeValue for Vec<f64> {
    fn typed(&self) -> Typed {
        Typed::FloatList(self.clone())
    }
    fn from_typed(value: Typed) -> Option<Self> {
        match value {
            Typed::FloatList(list) => Some(list),
            _ => None,
        }
    }
}

impl NodeValue for Vec<String> {
    fn typed(&self) -> Typed {
        Typed::TextList(self.clone())
    }
    fn from_typed(value: Typed) -> Option<Self> {
        match value {
            Typed::TextList(list) => Some(list),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origins_are_scheme_host_and_port_only() {
        for ok in [
            "http://localhost:3000",
            "https://lab.example.org",
            "http://127.0.0.1",
            "http://x:0",
            "http://x:65535",
            "http://[::1]:8080",
            "https://[2001:db8::1]",
        ] {
            assert_eq!(TextEntry::Origin.problem(ok), None, "{ok}");
        }
        for (bad, why) in [
            ("*", "wildcard"),
            ("http://*", "wildcards"),
            ("ftp://x", "must start with"),
            ("HTTP://x", "must start with"),
            ("localhost:3000", "must start with"),
            ("http://", "host is missing"),
            ("http://:80", "host is missing"),
            ("http://x/", "path"),
            ("http://x/path", "path"),
            ("http://x?q", "query"),
            ("http://x#f", "fragment"),
            ("http://u@x", "user name"),
            ("http://x\ty", "white space"),
            ("http://x:", "port"),
            ("http://x:65536", "port"),
            ("http://x:+80", "port"),
            ("http://x:1:2", "port"),
            ("http://[::1", "closing"),
            ("http://[::1]x", "only"),
            ("http://[]:80", "host is missing"),
        ] {
            let problem = TextEntry::Origin
                .problem(bad)
                .unwrap_or_else(|| panic!("{bad}"));
            assert!(problem.contains(why), "{bad}: {problem}");
        }
    }
}
