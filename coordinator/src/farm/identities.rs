//! The identities the farm trusts or bans as one. A worker's identity is who proved
//! itself when it registered: a certificate's fingerprint or a token's caller. Its
//! workers are registrations of it: they share its record (how many of its results were
//! taken, which sets how many are checked), its refusals (malformed results) and its
//! ban, which outlives every registration and, through [`Bans`], a restart.
//!
//! On a farm without access control nothing tells two callers apart, so each
//! registration is an identity of its own (such a farm listens only on loopback).

use std::collections::{BTreeMap, HashMap};
use std::time::{Instant, SystemTime};

use super::ids::IdentityId;

/// Malformed results an identity may return before it is banned: a bug may send one;
/// a worker whose every result is refused only costs the farm its leases.
pub const MAX_REFUSED: u32 = 3;

/// Most identities the farm keeps a record of; past it, those with no live worker and
/// no ban are forgotten, least recently seen first (a ban is never forgotten).
const MAX_RECORDS: usize = 4096;

/// Why and when an identity was banned.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Ban {
    pub reason: String,
    pub at: SystemTime,
}

#[derive(Clone, Debug)]
pub struct Identity {
    pub id: IdentityId,
    /// The certificate's fingerprint or the token's caller, or `registration N` on a
    /// farm without access control.
    pub name: String,
    /// Results taken from its workers (merged or held for a check): its record.
    pub answers: u64,
    /// Results refused as malformed.
    pub refused: u32,
    /// Units other identities finished while its workers still held them, and its
    /// leases that lapsed, less one for each result it returned: a hoarder's climb, an
    /// honest one's do not.
    pub strikes: u32,
    pub banned: Option<Ban>,
    pub last_seen: Instant,
}

/// Every identity the farm knows, by id and by name.
#[derive(Default)]
pub struct Identities {
    by_id: BTreeMap<IdentityId, Identity>,
    by_name: HashMap<String, IdentityId>,
    next: IdentityId,
    /// Bans changed since [`Identities::take_changed`]: the store must write them.
    changed: bool,
}

impl Identities {
    /// The identity called `name`, made (with an empty record, or the ban `bans` held
    /// for it) if it is new.
    pub fn named(&mut self, name: &str, now: Instant) -> &mut Identity {
        let id = match self.by_name.get(name) {
            Some(&id) => id,
            None => self.add(name.to_string(), None, now),
        };
        let identity = self.by_id.get_mut(&id).expect("indexed");
        identity.last_seen = now;
        identity
    }

    /// A new identity for one registration on a farm without access control.
    pub fn anonymous(&mut self, now: Instant) -> IdentityId {
        let name = format!("registration {}", self.next + 1);
        self.add(name, None, now)
    }

    fn add(&mut self, name: String, banned: Option<Ban>, now: Instant) -> IdentityId {
        self.next += 1;
        let id = self.next;
        self.by_name.insert(name.clone(), id);
        self.by_id.insert(id, Identity { id, name, answers: 0, refused: 0, strikes: 0, banned, last_seen: now });
        id
    }

    pub fn get(&self, id: IdentityId) -> Option<&Identity> {
        self.by_id.get(&id)
    }

    pub fn get_mut(&mut self, id: IdentityId) -> Option<&mut Identity> {
        self.by_id.get_mut(&id)
    }

    pub fn is_banned(&self, id: IdentityId) -> bool {
        self.by_id.get(&id).is_some_and(|i| i.banned.is_some())
    }

    /// Bans `id` for `reason`; false if it already was.
    pub fn ban(&mut self, id: IdentityId, reason: String) -> bool {
        let Some(i) = self.by_id.get_mut(&id) else { return false };
        if i.banned.is_some() {
            return false;
        }
        i.banned = Some(Ban { reason, at: SystemTime::now() });
        self.changed = true;
        true
    }

    /// Lifts the ban on `name`, and starts its record afresh (it is checked as a new
    /// identity). Returns the ban lifted, if there was one.
    pub fn unban(&mut self, name: &str) -> Option<Ban> {
        let i = self.by_id.get_mut(self.by_name.get(name)?)?;
        let ban = i.banned.take()?;
        (i.answers, i.refused) = (0, 0);
        self.changed = true;
        Some(ban)
    }

    /// Every identity, in the order they were first seen.
    pub fn iter(&self) -> impl Iterator<Item = &Identity> {
        self.by_id.values()
    }

    /// The bans, for the store.
    pub fn bans(&self) -> Bans {
        Bans(self.by_id.values().filter_map(|i| Some((i.name.clone(), i.banned.clone()?))).collect())
    }

    /// Bans read back from the store, at start.
    pub fn restore(&mut self, bans: Bans, now: Instant) {
        for (name, ban) in bans.0 {
            match self.by_name.get(&name) {
                Some(id) => self.by_id.get_mut(id).expect("indexed").banned = Some(ban),
                None => {
                    self.add(name, Some(ban), now);
                }
            }
        }
    }

    /// Whether the bans changed since the last call (the store writes them then).
    pub fn take_changed(&mut self) -> bool {
        std::mem::take(&mut self.changed)
    }

    /// The bans must be written again (the last write failed).
    pub fn mark_changed(&mut self) {
        self.changed = true;
    }

    /// Forgets records past [`MAX_RECORDS`] of identities with no live worker (`live`)
    /// and no ban, least recently seen first.
    pub fn forget_idle(&mut self, live: impl Fn(IdentityId) -> bool) {
        if self.by_id.len() <= MAX_RECORDS {
            return;
        }
        let mut idle: Vec<(Instant, IdentityId)> =
            self.by_id.values().filter(|i| i.banned.is_none() && !live(i.id)).map(|i| (i.last_seen, i.id)).collect();
        idle.sort_unstable();
        for (_, id) in idle.into_iter().take(self.by_id.len() - MAX_RECORDS) {
            if let Some(i) = self.by_id.remove(&id) {
                self.by_name.remove(&i.name);
            }
        }
    }
}

/// The farm's bans as the store keeps them (`bans.json` beside the checkpoints): a
/// table per banned identity, its name, why and when.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Bans(pub Vec<(String, Ban)>);

#[derive(serde::Serialize, serde::Deserialize)]
struct BanFile {
    #[serde(default)]
    ban: Vec<BanEntry>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct BanEntry {
    identity: String,
    reason: String,
    /// Seconds since 1970.
    at: u64,
}

/// Longest bans file read back.
const MAX_BANS_FILE_BYTES: u64 = 16 << 20;

impl Bans {
    pub fn to_json(&self) -> String {
        let since = |t: SystemTime| t.duration_since(SystemTime::UNIX_EPOCH).map_or(0, |d| d.as_secs());
        let ban = self
            .0
            .iter()
            .map(|(identity, b)| BanEntry { identity: identity.clone(), reason: b.reason.clone(), at: since(b.at) })
            .collect();
        serde_json::to_string_pretty(&BanFile { ban }).expect("bans serialise")
    }

    pub fn from_json(text: &str) -> Result<Self, String> {
        let file: BanFile = serde_json::from_str(text).map_err(|e| e.to_string())?;
        let at = |s: u64| SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(s);
        Ok(Self(file.ban.into_iter().map(|b| (b.identity, Ban { reason: b.reason, at: at(b.at) })).collect()))
    }

    /// Reads `path` (none there: no bans), within [`MAX_BANS_FILE_BYTES`].
    pub fn read(path: &std::path::Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let size = match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::default()),
            m => m.with_context(|| path.display().to_string())?.len(),
        };
        anyhow::ensure!(size <= MAX_BANS_FILE_BYTES, "{}: {size} bytes, more than a bans file holds", path.display());
        let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
        Self::from_json(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// Writes `path` atomically (a temporary file, synced, renamed over it).
    pub fn write(&self, path: &std::path::Path) -> anyhow::Result<()> {
        use anyhow::Context;
        use std::io::Write;
        let tmp = path.with_extension("json.tmp");
        let mut f = std::fs::File::create(&tmp).with_context(|| format!("writing {}", tmp.display()))?;
        f.write_all(self.to_json().as_bytes())
            .and_then(|()| f.sync_all())
            .with_context(|| tmp.display().to_string())?;
        std::fs::rename(&tmp, path).with_context(|| format!("replacing {}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ban_outlives_registrations_and_restarts_and_can_be_lifted() {
        let now = Instant::now();
        let mut ids = Identities::default();
        let liar = ids.named("cert:0123", now).id;
        ids.named("cert:0123", now).answers = 9;
        assert_eq!(ids.named("cert:0123", now).id, liar, "one identity, however often it registers");
        assert!(ids.ban(liar, "returned a wrong result".into()));
        assert!(!ids.ban(liar, "again".into()), "banned once");
        assert!(ids.take_changed() && !ids.take_changed());
        let text = ids.bans().to_json();
        let mut after = Identities::default();
        after.restore(Bans::from_json(&text).unwrap(), now);
        let back = after.named("cert:0123", now);
        assert_eq!(back.banned.as_ref().map(|b| b.reason.as_str()), Some("returned a wrong result"));
        let id = back.id;
        assert!(after.is_banned(id));
        assert!(after.unban("cert:0123").is_some());
        assert!(!after.is_banned(id) && after.unban("cert:0123").is_none());
        assert!(after.bans().0.is_empty() && after.take_changed());
        assert_ne!(ids.anonymous(now), ids.anonymous(now), "each registration of an open farm is its own");
        assert!(Bans::from_json(r#"{"ban": [{"identity": 3}]}"#).is_err());
    }

    #[test]
    fn idle_records_are_forgotten_past_the_limit_but_bans_are_kept() {
        let now = Instant::now();
        let mut ids = Identities::default();
        let banned = ids.named("banned", now).id;
        ids.ban(banned, "lied".into());
        for n in 0..MAX_RECORDS + 10 {
            ids.named(&format!("cert:{n}"), now + std::time::Duration::from_millis(n as u64));
        }
        ids.forget_idle(|_| false);
        assert_eq!(ids.iter().count(), MAX_RECORDS);
        assert!(ids.is_banned(banned));
        assert!(!ids.by_name.contains_key("cert:0") && ids.by_name.contains_key(&format!("cert:{}", MAX_RECORDS + 9)));
    }
}
