//! Reading a frame's counters back a frame late: the copy is recorded into the frame's own submission, mapped
//! when the GPU gets to it, and read at the next frame, so that no frame waits for its own GPU work.

use super::{GpuContext, GpuError};

/// Two staging buffers taken in turn: a frame copies into one while the last frame's copy, in the other, is
/// read.
#[derive(Debug)]
pub(super) struct LateRead<T> {
    slots: [LateSlot<T>; 2],
    /// The slot the next frame copies into.
    next: usize,
}

/// One staging buffer and the copy it waits for.
#[derive(Debug)]
struct LateSlot<T> {
    staging: wgpu::Buffer,
    /// The submission that copies into it, its map's outcome when it arrives, and what the caller tagged the
    /// copy with; `None` when free.
    pending: Option<Pending<T>>,
}

#[derive(Debug)]
struct Pending<T> {
    submission: wgpu::SubmissionIndex,
    mapped: std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
    tag: T,
}

impl<T> LateRead<T> {
    /// Two staging buffers of `size` bytes.
    pub(super) fn new(context: &GpuContext, size: u64) -> Self {
        let slot = || LateSlot {
            staging: context.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("late read"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            pending: None,
        };
        Self { slots: [slot(), slot()], next: 0 }
    }

    /// Records into `encoder` a copy of `source`'s first bytes (the staging buffers' size) into the free slot;
    /// [`LateRead::submitted`] must follow with the submission of `encoder`. Returns the slot.
    pub(super) fn record(&mut self, encoder: &mut wgpu::CommandEncoder, source: &wgpu::Buffer) -> usize {
        let slot = self.next;
        let staging = &self.slots[slot].staging;
        encoder.copy_buffer_to_buffer(source, 0, staging, 0, staging.size());
        slot
    }

    /// The copy recorded into `slot` was submitted as `submission`: its map starts (it completes when the GPU
    /// is done with it), tagged with what the caller needs to read it (`tag`).
    pub(super) fn submitted(&mut self, slot: usize, submission: wgpu::SubmissionIndex, tag: T) {
        let (sender, mapped) = std::sync::mpsc::channel();
        self.slots[slot].staging.slice(..).map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        self.slots[slot].pending = Some(Pending { submission, mapped, tag });
        self.next = 1 - slot;
    }

    /// The bytes and tag of the copy before the last one submitted (the previous frame's), waiting for that
    /// submission alone; `None` where there is none (the first frame, or after [`LateRead::forget`]).
    ///
    /// # Errors
    /// [`GpuError::Lost`] when the device is lost or the map fails.
    pub(super) fn take_previous(&mut self, context: &GpuContext) -> Result<Option<(Vec<u8>, T)>, GpuError> {
        let slot = &mut self.slots[self.next];
        let Some(Pending { submission, mapped, tag }) = slot.pending.take() else { return Ok(None) };
        let lost = |what: &str, error: &dyn std::fmt::Display| GpuError::Lost(format!("{what}: {error}"));
        let wait = wgpu::PollType::Wait { submission_index: Some(submission), timeout: None };
        context.device.poll(wait).map_err(|e| lost("waiting for the last frame", &e))?;
        mapped.recv().map_err(|e| lost("map callback dropped", &e))?.map_err(|e| lost("map failed", &e))?;
        let bytes = slot.staging.slice(..).get_mapped_range().map_err(|e| lost("mapped range", &e))?.to_vec();
        slot.staging.unmap();
        Ok(Some((bytes, tag)))
    }

    /// Drops the copy still pending (its frame's counters will not be read), waiting for it so that its slot
    /// is free again.
    ///
    /// # Errors
    /// As [`LateRead::take_previous`].
    pub(super) fn forget(&mut self, context: &GpuContext) -> Result<(), GpuError> {
        self.next = 1 - self.next;
        let pending = self.take_previous(context);
        self.next = 1 - self.next;
        pending.map(|_| ())
    }
}
