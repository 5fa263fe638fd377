//! What every section's Markdown shares.

/// A Markdown table cell: pipes escaped, one line.
pub(crate) fn cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}
