//! Per-actor tokens (`dvnav learner --actor-tokens FILE`): each actor name has its own token,
//! so a leaked token speaks for one actor only, and one actor can be shut out by removing its
//! line.
//!
//! The file holds one `NAME TOKEN` pair per line (whitespace between; `#` starts a comment;
//! blank lines are skipped). With it, registering a listed name needs that name's token; a
//! name not listed needs the shared token (`--token-file`), and is refused when there is none.
//! Any listed token (or the shared one) lets a caller use the other calls, whose streams are
//! bound to a registration's session anyway.

use std::collections::BTreeMap;
use std::path::Path;

/// The token of each actor name.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ActorTokens {
    by_name: BTreeMap<String, String>,
}

impl ActorTokens {
    /// Parses the file's text (see the module docs); an error names the line.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let mut by_name = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or_default().trim();
            if line.is_empty() {
                continue;
            }
            let mut parts = line.split_whitespace();
            let (Some(name), Some(token), None) = (parts.next(), parts.next(), parts.next()) else {
                anyhow::bail!("line {}: expected `NAME TOKEN`", i + 1);
            };
            if by_name.insert(name.to_string(), token.to_string()).is_some() {
                anyhow::bail!("line {}: actor {name:?} is listed twice", i + 1);
            }
        }
        anyhow::ensure!(!by_name.is_empty(), "no `NAME TOKEN` line");
        Ok(Self { by_name })
    }

    /// Reads and parses `path`.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))
    }

    /// The token of `name`, when the file lists it.
    pub fn token_of(&self, name: &str) -> Option<&str> {
        self.by_name.get(name).map(String::as_str)
    }

    /// Whether `presented` is some listed actor's token (compared in constant time).
    pub fn accepts_any(&self, presented: Option<&str>) -> bool {
        // Every entry is compared, so the time does not tell which one matched.
        self.by_name
            .values()
            .fold(false, |ok, t| ok | dvnav_tls::auth::token_accepted(Some(t), presented))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_pairs_and_refuses_bad_lines() {
        let t = ActorTokens::parse("# fleet\nactor-0 t0\n\n  actor-1\tt1  # lab\n").unwrap();
        assert_eq!((t.token_of("actor-0"), t.token_of("actor-1")), (Some("t0"), Some("t1")));
        assert_eq!(t.token_of("actor-2"), None);
        assert!(t.accepts_any(Some("t1")) && !t.accepts_any(Some("t2")) && !t.accepts_any(None));
        let err = |s| ActorTokens::parse(s).unwrap_err().to_string();
        assert!(err("a t\nb\n").contains("line 2"), "{}", err("a t\nb\n"));
        assert!(err("a t x\n").contains("line 1"));
        assert!(err("a t\na u\n").contains("twice"));
        assert!(err("# nothing\n").contains("no `NAME TOKEN`"));
    }
}
