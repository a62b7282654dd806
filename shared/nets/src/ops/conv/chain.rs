//! A chain of convolutions — each layer's output the next one's input, as the
//! 3D-TCN's frame layers — as one candle op with its own backward pass.
//!
//! Candle's backward pass starts every node's gradient as a zero tensor and adds each
//! incoming gradient into a new one, so between two convolutions it zero-fills, adds
//! and allocates every activation-sized gradient (the CPU preset's largest tensors;
//! with the convolutions' own zeroed buffers ≈ 13 % of a real run's learner,
//! docs/performance.md). Inside this op the chain's activations and their gradients
//! never become candle tensors: the forward pass runs the convolution's forward driver
//! layer by layer and keeps each layer's output; the backward pass runs its backward
//! driver from the last layer to the first, each input gradient feeding the layer
//! before as its output gradient. Candle sees two arguments, the chain's input and
//! every layer's weight and bias packed in one vector ([`conv_chain`] packs them with
//! `Tensor::cat`, whose own backward hands each parameter its slice of the packed
//! gradient).
//!
//! Invariant: outputs and gradients are exactly those of the same layers applied one
//! by one with [`conv`](super::conv) — the same drivers on the same values in the same
//! order (tested bit for bit on every instruction-set path, and against finite
//! differences).

use std::sync::OnceLock;

use candle_core::{CpuStorage, CustomOp2, Layout, Shape, Tensor};

use super::geometry::Geometry;
use super::{ConvSpec, backward, forward};
use crate::ops::{cpu_f32, with_cpu_f32};

/// One layer of a chain: where its weight and bias sit in the packed parameters.
#[derive(Debug, Clone)]
struct Layer {
    spec: ConvSpec,
    /// The weight's shape (K, C_out).
    w_dims: [usize; 2],
    /// Offset of the weight in the packed parameters; the bias (C_out) follows it.
    offset: usize,
}

impl Layer {
    fn w_len(&self) -> usize {
        self.w_dims[0] * self.w_dims[1]
    }

    /// The layer's weight and bias within the packed parameters.
    fn params<'a>(&self, packed: &'a [f32]) -> (&'a [f32], &'a [f32]) {
        let (w, rest) = packed[self.offset..].split_at(self.w_len());
        (w, &rest[..self.w_dims[1]])
    }

    /// The same, to write gradients into.
    fn params_mut<'a>(&self, packed: &'a mut [f32]) -> (&'a mut [f32], &'a mut [f32]) {
        let (w, rest) = packed[self.offset..].split_at_mut(self.w_len());
        (w, &mut rest[..self.w_dims[1]])
    }
}

/// The custom op. Use [`conv_chain`] rather than this directly.
struct ConvChainOp {
    layers: Vec<Layer>,
    /// Whether the forward pass keeps the activations for a backward pass (when the
    /// input or the parameters take part in a gradient).
    keep: bool,
    /// The outputs of every layer but the last (the inputs of layers 1 …), set once by
    /// the forward pass when `keep` and only read after it (by any number of backward
    /// passes, concurrently, without a lock).
    activations: OnceLock<Vec<Vec<f32>>>,
}

impl ConvChainOp {
    fn packed_len(&self) -> usize {
        self.layers.iter().map(|l| l.w_len() + l.w_dims[1]).sum()
    }

    /// Every layer's geometry for an input of `dims`.
    fn geometries(&self, dims: &[usize]) -> candle_core::Result<Vec<Geometry>> {
        let mut dims = dims.to_vec();
        let mut out = Vec::with_capacity(self.layers.len());
        for layer in &self.layers {
            let g = Geometry::new(layer.spec, &dims, &layer.w_dims)?;
            dims = vec![g.b, g.to, g.ho, g.wo, g.co];
            out.push(g);
        }
        Ok(out)
    }

    /// Gradients of the packed parameters and, where `need_dx`, of the input.
    fn gradients(
        &self,
        geometries: &[Geometry],
        x: &[f32],
        packed: &[f32],
        y: &[f32],
        dy: &[f32],
        need_dx: bool,
    ) -> candle_core::Result<(Option<Vec<f32>>, Vec<f32>)> {
        let last = self.layers.len() - 1;
        let Some(activations) = self.activations.get().filter(|a| a.len() == last) else {
            candle_core::bail!("conv chain: backward without the forward pass's activations (it kept none)");
        };
        let mut grads = vec![0f32; packed.len()];
        let mut upstream: Vec<f32> = Vec::new();
        let mut dx0 = None;
        for (i, (layer, g)) in self.layers.iter().zip(geometries).enumerate().rev() {
            let input: &[f32] = if i == 0 { x } else { &activations[i - 1] };
            let output: &[f32] = if i == last { y } else { &activations[i] };
            let dy_i: &[f32] = if i == last { dy } else { &upstream };
            let (w, _) = layer.params(packed);
            let (dx, dw, db) = backward(g, input, w, output, dy_i, i > 0 || need_dx);
            let (gw, gb) = layer.params_mut(&mut grads);
            gw.copy_from_slice(&dw);
            gb.copy_from_slice(&db);
            match dx {
                Some(dx) if i > 0 => upstream = dx,
                dx => dx0 = dx,
            }
        }
        Ok((dx0, grads))
    }
}

impl CustomOp2 for ConvChainOp {
    fn name(&self) -> &'static str {
        "pednav-conv-chain"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = cpu_f32(s1, l1, "input")?;
        let packed = cpu_f32(s2, l2, "packed parameters")?;
        if packed.len() != self.packed_len() {
            candle_core::bail!("conv chain: {} packed parameters, the layers need {}", packed.len(), self.packed_len());
        }
        let geometries = self.geometries(l1.dims())?;
        let mut kept = Vec::with_capacity(self.layers.len() - 1);
        let mut current: Option<Vec<f32>> = None;
        for (layer, g) in self.layers.iter().zip(&geometries) {
            let (w, b) = layer.params(packed);
            let y = forward(g, current.as_deref().unwrap_or(x), w, b);
            if let Some(previous) = current.replace(y)
                && self.keep
            {
                kept.push(previous);
            }
        }
        if self.keep && self.activations.set(kept).is_err() {
            candle_core::bail!("conv chain: one op ran its forward pass twice");
        }
        let g = geometries.last().expect("a chain has layers");
        let y = current.expect("a chain has layers");
        Ok((CpuStorage::F32(y), Shape::from_dims(&[g.b, g.to, g.ho, g.wo, g.co])))
    }

    fn bwd(
        &self,
        x: &Tensor,
        packed: &Tensor,
        y: &Tensor,
        dy: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let geometries = self.geometries(x.dims())?;
        let dy = dy.contiguous()?;
        let need_dx = x.track_op();
        let (dx, grads) = with_cpu_f32(x, "input", |xs| {
            with_cpu_f32(packed, "packed parameters", |ps| {
                with_cpu_f32(y, "output", |ys| {
                    with_cpu_f32(&dy, "output gradient", |dys| self.gradients(&geometries, xs, ps, ys, dys, need_dx))
                })
            })
        })?;
        let dev = x.device();
        let dx = dx.map(|v| Tensor::from_vec(v, x.shape(), dev)).transpose()?;
        Ok((dx, Some(Tensor::from_vec(grads, packed.shape(), dev)?)))
    }
}

/// `layers` (weight, bias, spec) applied in turn to `x`: the same values as folding
/// [`conv`](super::conv) over them, as one op on the CPU (see the module docs); on
/// other devices, and for a single layer, the fold itself.
pub fn conv_chain(x: &Tensor, layers: &[(&Tensor, &Tensor, ConvSpec)]) -> candle_core::Result<Tensor> {
    if !x.device().is_cpu() || layers.len() < 2 {
        return layers.iter().try_fold(x.clone(), |x, &(w, b, spec)| super::conv(&x, w, b, spec));
    }
    let mut parts = Vec::with_capacity(2 * layers.len());
    let mut packed_layers = Vec::with_capacity(layers.len());
    let mut offset = 0;
    for &(w, b, spec) in layers {
        let &[k, co] = w.dims() else {
            candle_core::bail!("conv chain: weight must be (K, C_out), got {:?}", w.dims());
        };
        if b.dims() != [co] {
            candle_core::bail!("conv chain: bias must be ({co}), got {:?}", b.dims());
        }
        packed_layers.push(Layer { spec, w_dims: [k, co], offset });
        offset += k * co + co;
        parts.push(w.flatten_all()?);
        parts.push(b.clone());
    }
    let packed = Tensor::cat(&parts, 0)?;
    let keep = packed.track_op() || x.track_op();
    let op = ConvChainOp { layers: packed_layers, keep, activations: OnceLock::new() };
    x.contiguous()?.apply_op2(&packed, op)
}
