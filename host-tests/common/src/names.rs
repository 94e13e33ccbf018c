//! "Did you mean": the closest known name to a mistyped one, for every file format and
//! command line that refuses an unknown word (the model lab's terms, the Monte Carlo
//! campaign's keys and fields).

/// The closest of `names` to `word` (case and `_` aside, at most 2 edits, or a name the
/// word begins), as a "did you mean" clause.
pub fn did_you_mean<'a>(word: &str, names: impl Iterator<Item = &'a str>) -> String {
    let norm = |s: &str| s.to_lowercase().replace(['_', '-'], "");
    names
        .map(|n| {
            let (w, m) = (norm(word), norm(n));
            // A name the word begins (`chamber_rh` of `chamber_rh_pct`) counts as one edit.
            (if w.len() >= 3 && m.starts_with(&w) && w != m { 1 } else { strsim::levenshtein(&w, &m) }, n)
        })
        .filter(|(d, _)| *d <= 2)
        .min_by_key(|(d, _)| *d)
        .map_or(String::new(), |(_, n)| format!("; did you mean `{n}`?"))
}

/// A serde message about an unknown key or variant (`unknown field `x`, expected one of
/// `a`, `b``, as `deny_unknown_fields` and enums give it) with the "did you mean" clause of
/// the closest expected name appended; any other message unchanged.
pub fn with_suggestion(message: &str) -> String {
    let hint = ["unknown field `", "unknown variant `"].iter().find_map(|head| {
        let start = message.find(head)? + head.len();
        let (word, rest) = message[start..].split_once('`')?;
        let expected = rest.split_once("expected")?.1.lines().next()?;
        let names = expected.split('`').skip(1).step_by(2);
        Some(did_you_mean(word, names))
    });
    match hint {
        Some(h) if !h.is_empty() => {
            let trimmed = message.trim_end();
            format!("{trimmed}{h}")
        }
        _ => message.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suggests_the_nearest_expected_name() {
        let m = "TOML parse error at line 3, column 1\n  |\n3 | rnus = 1\n  | ^^^^\nunknown field `rnus`, expected one of `runs`, `seed`\n";
        assert!(with_suggestion(m).ends_with("; did you mean `runs`?"), "{}", with_suggestion(m));
        let v = "unknown variant `normel`, expected one of `normal`, `uniform`";
        assert!(with_suggestion(v).ends_with("did you mean `normal`?"));
        assert_eq!(
            with_suggestion("unknown field `zzzzzz`, expected `runs`"),
            "unknown field `zzzzzz`, expected `runs`"
        );
        assert_eq!(with_suggestion("missing field `runs`"), "missing field `runs`");
    }
}
