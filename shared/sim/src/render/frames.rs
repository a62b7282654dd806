//! Read-back of one render call: [`Frames`] hands out each view's rows straight
//! from the renderer's mapped readback buffer (the atlas, rows padded to 256
//! bytes), so a consumer copies each frame exactly once.
//!
//! Invariant: while a [`Frames`] is alive the readback buffer stays mapped and the
//! renderer stays borrowed, so `render` cannot run and remap it; dropping `Frames`
//! unmaps it, once, and only if something was mapped (an empty call maps nothing).

use super::Renderer;

/// The mapped result of one [`Renderer::render`] call; unmaps on drop.
pub struct Frames<'a> {
    /// The mapped rows of the readback buffer; `None` when no view was rendered.
    pub(super) view: Option<wgpu::BufferView>,
    /// The renderer whose readback buffer is mapped (its atlas layout gives the rows).
    pub(super) renderer: &'a Renderer,
    /// Number of views rendered.
    pub(super) count: usize,
}

impl Frames<'_> {
    /// Number of views.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True when no view was rendered.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Side of each view in pixels.
    pub fn image_size(&self) -> u32 {
        self.renderer.config.image_size
    }

    /// Row `row` (0 = top) of view `i`, straight from the mapped buffer.
    #[inline]
    pub fn row(&self, i: usize, row: u32) -> &[u8] {
        assert!(i < self.count, "view {i} out of {}", self.count);
        let r = self.renderer;
        let size = r.config.image_size;
        let (c, gr) = (i as u32 % r.cols, i as u32 / r.cols);
        let start = ((gr * size + row) * r.padded_bpr + c * size) as usize;
        let data: &[u8] = self.view.as_deref().expect("non-empty frames are mapped");
        &data[start..start + size as usize]
    }

    /// Copy view `i` into `dst` (`image_size²` bytes, row-major, top row first).
    pub fn copy_frame(&self, i: usize, dst: &mut [u8]) {
        let size = self.image_size() as usize;
        assert_eq!(dst.len(), size * size, "destination must hold one {size}×{size} frame");
        for (row, chunk) in dst.chunks_exact_mut(size).enumerate() {
            chunk.copy_from_slice(self.row(i, row as u32));
        }
    }

    /// Copy view `i` into uninitialised memory (a loaned shared-memory sample, say),
    /// initialising all `image_size²` bytes of `dst`.
    pub fn copy_frame_uninit(&self, i: usize, dst: &mut [std::mem::MaybeUninit<u8>]) {
        let size = self.image_size() as usize;
        assert_eq!(dst.len(), size * size, "destination must hold one {size}×{size} frame");
        for (row, chunk) in dst.chunks_exact_mut(size).enumerate() {
            let src = self.row(i, row as u32);
            // SAFETY: `chunk` and `src` are `size` bytes each and cannot overlap
            // (one is mapped GPU memory, the other the caller's buffer); u8 has no
            // invalid bit patterns, so writing initialises the chunk.
            unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), chunk.as_mut_ptr().cast::<u8>(), size) };
        }
    }

    /// View `i` as a new vector.
    pub fn frame(&self, i: usize) -> Vec<u8> {
        let size = self.image_size() as usize;
        let mut v = vec![0; size * size];
        self.copy_frame(i, &mut v);
        v
    }
}

impl Drop for Frames<'_> {
    fn drop(&mut self) {
        if self.view.take().is_some() {
            self.renderer.readback.unmap();
        }
    }
}
