//! The mirror's change list: which ranges of its state a frame wrote, for a
//! renderer to upload (merged, bounded, restored when a frame is rolled
//! back).

use std::ops::Range;

/// A range of a mirror's state that changed.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Change {
    /// The instance was defined or redefined: upload everything.
    Defined(u32),
    /// The instance was removed.
    Removed(u32),
    /// The instance's transform changed.
    Transform(u32),
    /// Bucket entries `range` of the instance changed.
    Buckets(u32, Range<u32>),
    /// Words `range` of the instance changed.
    Words(u32, Range<u32>),
}

/// What changed since the last [`Mirror::take_changes`](crate::Mirror::take_changes) or
/// [`Mirror::clear_changes`](crate::Mirror::clear_changes). After a rejected frame the list may
/// over-report (`all` set), never under-report.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Changes {
    /// Everything may have changed (a keyframe, or too many ranges to list).
    pub all: bool,
    /// Changed ranges in the order they were written; adjacent ranges merged.
    pub items: Vec<Change>,
}

/// Ranges listed before [`Changes::all`] is set instead.
const MAX_CHANGE_ITEMS: usize = 1 << 16;

/// The change list as it was before a delta, to restore on rollback. The
/// restored list may over-report (never under-report): if the failed frame
/// overflowed the list into `all`, `all` stays set.
pub(super) struct ChangeMark {
    all: bool,
    len: usize,
    last: Option<Change>,
}

impl ChangeMark {
    pub(super) fn of(changes: &Changes) -> ChangeMark {
        ChangeMark {
            all: changes.all,
            len: changes.items.len(),
            last: changes.items.last().cloned(),
        }
    }

    pub(super) fn restore(self, changes: &mut Changes) {
        if changes.all && !self.all {
            return;
        }
        changes.items.truncate(self.len);
        if let (Some(last), Some(slot)) = (self.last, changes.items.last_mut()) {
            *slot = last;
        }
    }
}

pub(super) fn push_change(changes: &mut Changes, change: Change) {
    if changes.all {
        return;
    }
    if let Some(last) = changes.items.last_mut() {
        match (last, &change) {
            (Change::Words(a, ra), Change::Words(b, rb))
            | (Change::Buckets(a, ra), Change::Buckets(b, rb))
                if a == b && ra.end >= rb.start && ra.start <= rb.start =>
            {
                ra.end = ra.end.max(rb.end);
                return;
            }
            _ => {}
        }
    }
    if changes.items.len() >= MAX_CHANGE_ITEMS {
        changes.all = true;
        changes.items.clear();
        return;
    }
    changes.items.push(change);
}
