//! How keys and values appear in messages: cut short when long, numbers compact.

use std::borrow::Cow;

use serde_json::Value;

use super::quantity::number;

/// Longest quoted key or value in a message, in characters.
pub(crate) const QUOTE_CHARS: usize = 80;

/// `text` as a message quotes it: whole up to [`QUOTE_CHARS`] characters, else its first
/// ones and `… (N bytes)`, so that a 20 MB key or value gives a short message.
pub(crate) fn cut(text: &str) -> Cow<'_, str> {
    match text.char_indices().nth(QUOTE_CHARS) {
        Some((end, _)) => Cow::Owned(format!("{}… ({} bytes)", &text[..end], text.len())),
        None => Cow::Borrowed(text),
    }
}

/// A JSON value as a message shows it: numbers compact, anything long cut short.
pub(crate) fn show_json(value: &Value) -> String {
    let text = match value.as_f64() {
        Some(x) if value.is_f64() => number(x),
        _ => value.to_string(),
    };
    cut(&text).into_owned()
}
