//! Where a resumed run starts: the cut layer's progress from the galvo or the journal, or the
//! operator's choice when neither can tell. Decided before anything is switched on.

use trim_cell::job::LayerKey;

use super::{CutLayerOutcome, ExecError, Executor};
use crate::galvo::outline::is_frame_tag;
use crate::galvo::protocol::NO_LIST;
use crate::journal::{CutLayer, Entry, Journal, JournalState};
use crate::record::LogLevel;

/// Where a resumed run starts the cut layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum CutStart {
    /// No cut layer.
    None,
    /// Continue the layer from this vector (known from the galvo or the journal).
    Continue(LayerKey, u32),
    /// The operator's choice for a layer of unknown progress.
    Chosen(LayerKey, CutLayer, u32),
}

impl CutStart {
    /// The cut layer this run continues, and the vector it continues from (not a chosen redo).
    pub(super) fn resumed_from(self) -> Option<(LayerKey, u32)> {
        match self {
            CutStart::Continue(k, v) => Some((k, v)),
            CutStart::None | CutStart::Chosen(..) => None,
        }
    }

    /// The first vector of layer `key` (of `n`) this run marks.
    pub(super) fn first_vector(self, key: LayerKey, n: u32) -> u32 {
        match self {
            CutStart::Continue(k, v) | CutStart::Chosen(k, CutLayer::Redo, v) if k == key => {
                v.min(n)
            }
            _ => 0,
        }
    }
}

impl Executor {
    /// Where the cut layer continues: the first vector the galvo did not mark, or the vector
    /// the journal's cut entry names; when neither can tell, the operator's choice
    /// ([`ExecOptions::cut_layer`]), journaled here, or [`ExecError::ResumeUnknown`]. Runs before
    /// anything is switched on.
    pub(super) async fn resume_point(
        &self,
        state: &JournalState,
        journal: &mut Journal,
    ) -> Result<(CutStart, Option<CutLayerOutcome>), ExecError> {
        let Some(Entry::LayerBegin {
            key,
            first_vector,
            tag,
            vectors,
        }) = &state.open_begin
        else {
            return Ok((CutStart::None, None));
        };
        let cut = match &state.open_cut {
            Some(Entry::LayerCut { vectors_done, .. }) => *vectors_done,
            _ => None,
        };
        let status = self.galvo_status().await.ok();
        let known = match status {
            Some(s) if s.list != NO_LIST && s.tag == *tag => Some(first_vector + s.marks_done),
            // The controller's last list is an earlier one of this run: this one never ran.
            Some(s)
                if s.list != NO_LIST
                    && s.tag >> 16 == tag >> 16
                    && s.tag < *tag
                    && !is_frame_tag(s.tag) =>
            {
                Some(cut.unwrap_or(*first_vector))
            }
            _ => cut,
        };
        if let Some(done) = known {
            // A count known only from the galvo is journaled at once: framing (`run --resume
            // --frame`, `trimctl frame`) replaces the galvo's list, so after a stop before this
            // layer begins again the count would be gone and the layer of unknown progress
            // (redo: vectors marked twice, or skip).
            if cut != Some(done) {
                journal
                    .append_within(
                        &Entry::LayerCut {
                            key: *key,
                            vectors_done: Some(done),
                            reason: format!(
                                "resume: the galvo reports {done} of the layer's vectors marked (list tag {tag})"
                            ),
                        },
                        self.options.timeouts.journal_write,
                    )
                    .await?;
            }
            return Ok((CutStart::Continue(*key, done), None));
        }
        let reason = match status {
            Some(s) if s.list == NO_LIST => format!(
                "the galvo does not report list tag {tag} (it has run no list since it started: restarted?) and the journal has no count"
            ),
            Some(s) => format!(
                "the galvo does not report list tag {tag} (it reports list {} tag {}) and the journal has no count",
                s.list, s.tag
            ),
            None => format!(
                "the galvo does not answer its status for list tag {tag} and the journal has no count"
            ),
        };
        let Some(choice) = self.options.cut_layer else {
            return Err(ExecError::ResumeUnknown {
                key: *key,
                reason,
                first_vector: *first_vector,
                vectors: *vectors,
            });
        };
        let vectors_maybe_twice = match choice {
            CutLayer::Redo => vectors.saturating_sub(*first_vector),
            CutLayer::Skip => 0,
        };
        let entry = Entry::CutLayerChoice {
            key: *key,
            choice,
            first_vector: *first_vector,
            vectors: *vectors,
            vectors_maybe_twice,
            reason: reason.clone(),
        };
        journal
            .append_within(&entry, self.options.timeouts.journal_write)
            .await?;
        self.log(
            LogLevel::Warning,
            &format!("resume: {key}: {reason}; operator chose {choice} ({vectors_maybe_twice} vectors may be marked twice)"),
        );
        Ok((
            CutStart::Chosen(*key, choice, *first_vector),
            Some(CutLayerOutcome {
                key: *key,
                choice,
                first_vector: *first_vector,
                vectors: *vectors,
                vectors_maybe_twice,
            }),
        ))
    }
}
