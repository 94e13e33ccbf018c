//! The command key's file on the ground: TOML with the key's id and its 32 bytes in hex.
//!
//! ```toml
//! id = 1
//! key = "…64 hex digits…"
//! ```
//!
//! The unit holds the same key as a record in its protected KEY region
//! (`ssis::telecommand::auth`; [`Key::to_record`]). A key file is a secret: it is written
//! readable by its owner only.

use std::path::Path;

use anyhow::{Context, Result};
use rand::TryRngCore;
use ssis::telecommand::auth::{Key, KEY_LEN};

#[derive(serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyFile {
    id: u16,
    key: String,
}

/// A new key with id `id` from the operating system's random source.
pub fn new_key(id: u16) -> Result<Key> {
    anyhow::ensure!(id >= 1, "a key id is at least 1");
    let mut bytes = [0u8; KEY_LEN];
    rand::rngs::OsRng.try_fill_bytes(&mut bytes).context("no random bytes from the operating system")?;
    Ok(Key { id, bytes })
}

/// Writes `key` to `path` (refused if it exists), readable by its owner only.
pub fn write_key(path: &Path, key: &Key) -> Result<()> {
    anyhow::ensure!(!path.exists(), "{} exists; not overwritten", path.display());
    let hex: String = key.bytes.iter().map(|b| format!("{b:02x}")).collect();
    let text = toml::to_string(&KeyFile { id: key.id, key: hex })?;
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))?;
    }
    Ok(())
}

/// Reads a key file.
pub fn read_key(path: &Path) -> Result<Key> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let f: KeyFile = toml::from_str(&text).with_context(|| format!("{}: not a key file", path.display()))?;
    anyhow::ensure!(f.id >= 1, "{}: key id 0", path.display());
    let hex = f.key.trim();
    anyhow::ensure!(
        hex.len() == 2 * KEY_LEN,
        "{}: the key is {} hex digits, not {}",
        path.display(),
        hex.len(),
        2 * KEY_LEN
    );
    let mut bytes = [0u8; KEY_LEN];
    for (b, pair) in bytes.iter_mut().zip(hex.as_bytes().chunks(2)) {
        let s = std::str::from_utf8(pair)?;
        *b = u8::from_str_radix(s, 16).with_context(|| format!("{}: {s:?} is not hex", path.display()))?;
    }
    Ok(Key { id: f.id, bytes })
}
