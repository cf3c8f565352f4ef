//! tanh and sigmoid for training on burn's `flex` backend, vectorized.
//!
//! flex computes both one element at a time with libm (`tanhf`, `expf`), and burn's autodiff
//! computes the forward again in the backward pass: with those, about half of single-thread
//! training goes there (`perf`: libm's `expm1f`, `tanhf`, `expf` and flex's unary loop, 47 %;
//! 5 % with the kernels here).
//! Here the forward is a branch-free f32 kernel LLVM vectorizes (Cephes' `expf` and `tanhf`
//! formulas; measured over the range: tanh within 1 ulp of the correctly rounded value, sigmoid
//! within 2, where glibc's `tanhf` and flex's libm-based sigmoid are within 2), registered
//! through burn's backend extension API, and the backward reuses the saved output in one pass:
//! `g (1 - y^2)` and `g y (1 - y)`, the expressions burn's own backward evaluates. Other backends
//! and other float types take burn's `tanh` and `sigmoid` unchanged.
use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{unary, Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ops::{ActivationOps, FloatTensorOps};
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    backend_extension, Autodiff, Backend, DispatchTensor, DispatchTensorKind, Flex,
};
use burn::prelude::*;
use burn::tensor::DType;

/// The activations as a burn backend extension (flex and autodiff over flex).
#[backend_extension(Flex, Autodiff)]
pub trait FastActivation: Backend {
    /// Element-wise tanh.
    fn fast_tanh(x: FloatTensor<Self>) -> FloatTensor<Self>;
    /// Element-wise logistic sigmoid, `1 / (1 + exp(-x))`.
    fn fast_sigmoid(x: FloatTensor<Self>) -> FloatTensor<Self>;
}

/// `x.tanh()`, vectorized on flex f32 tensors.
pub fn tanh<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    if !fast(&x) {
        return x.tanh();
    }
    Tensor::from_dispatch(<burn::backend::Dispatch as FastActivation>::fast_tanh(
        x.into_dispatch(),
    ))
}

/// `burn::tensor::activation::sigmoid(x)`, vectorized on flex f32 tensors.
pub fn sigmoid<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    if !fast(&x) {
        return burn::tensor::activation::sigmoid(x);
    }
    Tensor::from_dispatch(<burn::backend::Dispatch as FastActivation>::fast_sigmoid(
        x.into_dispatch(),
    ))
}

/// Whether `x` is an f32 tensor on flex (with or without autodiff).
fn fast<const D: usize>(x: &Tensor<D>) -> bool {
    x.dtype() == DType::F32 && on_flex(&x.clone().into_dispatch())
}

#[allow(unreachable_patterns)] // with only flex enabled, flex is the only kind
fn on_flex(t: &DispatchTensor) -> bool {
    match &t.kind {
        DispatchTensorKind::Flex(_) => true,
        DispatchTensorKind::Autodiff(inner) => matches!(**inner, DispatchTensorKind::Flex(_)),
        _ => false,
    }
}

impl FastActivation for Flex {
    fn fast_tanh(x: FlexTensor) -> FlexTensor {
        if x.dtype() != DType::F32 {
            return Flex::float_tanh(x);
        }
        map(x, tanh_f32)
    }

    fn fast_sigmoid(x: FlexTensor) -> FlexTensor {
        if x.dtype() != DType::F32 {
            return Flex::sigmoid(x);
        }
        map(x, sigmoid_f32)
    }
}

impl<C: CheckpointStrategy> FastActivation for Autodiff<Flex, C> {
    fn fast_tanh(x: FloatTensor<Self>) -> FloatTensor<Self> {
        from_output::<C>(FromOutput::Tanh, x)
    }

    fn fast_sigmoid(x: FloatTensor<Self>) -> FloatTensor<Self> {
        from_output::<C>(FromOutput::Sigmoid, x)
    }
}

/// An activation whose backward pass needs only its output `y`, which the forward saves.
#[derive(Debug, Clone, Copy)]
enum FromOutput {
    /// `g (1 - y^2)`.
    Tanh,
    /// `g y (1 - y)`, flex's own `sigmoid_backward`.
    Sigmoid,
}

impl Backward<Flex, 1> for FromOutput {
    /// The output y.
    type State = FlexTensor;

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let y = ops.state;
        unary::<Flex, _>(ops.parents, ops.node, grads, |g| match (self, y.dtype() == DType::F32) {
            (FromOutput::Tanh, true) => zip(y, g, |y, g| g * (1.0 - y * y)),
            (FromOutput::Tanh, false) => {
                let one_minus = Flex::float_add_scalar(Flex::float_neg(Flex::float_mul(y.clone(), y)), 1f32.into());
                Flex::float_mul(g, one_minus)
            }
            (FromOutput::Sigmoid, true) => zip(y, g, |s, g| g * s * (1.0 - s)),
            (FromOutput::Sigmoid, false) => Flex::sigmoid_backward(y, g),
        });
    }
}

/// The activation `kind` of `x` on flex, its output saved for the backward pass when tracked.
fn from_output<C: CheckpointStrategy>(kind: FromOutput, x: FloatTensor<Autodiff<Flex, C>>) -> FloatTensor<Autodiff<Flex, C>> {
    let forward = |x: FlexTensor| match kind {
        FromOutput::Tanh => Flex::fast_tanh(x),
        FromOutput::Sigmoid => Flex::fast_sigmoid(x),
    };
    match kind.prepare::<C>([x.node()]).compute_bound().stateful() {
        OpsKind::Tracked(prep) => {
            let y = forward(x.into_primitive());
            prep.finish(y.clone(), y)
        }
        OpsKind::UnTracked(prep) => prep.finish(forward(x.into_primitive())),
    }
}

/// `f` of every element of `x` (f32, any layout), in place when `x` owns its storage.
fn map(x: FlexTensor, f: impl Fn(f32) -> f32) -> FlexTensor {
    let mut x = x;
    if !(x.is_unique() && x.layout().is_contiguous() && x.layout().start_offset() == 0) {
        x = x.to_contiguous();
    }
    if x.is_unique() && x.layout().start_offset() == 0 {
        let n = x.layout().num_elements();
        each(&mut x.storage_mut::<f32>()[..n], f);
        return x;
    }
    // Contiguous already but shared (autodiff keeps it): a copy.
    let shape = x.layout().shape().clone();
    let (n, start) = (x.layout().num_elements(), x.layout().start_offset());
    let mut out = x.storage::<f32>()[start..start + n].to_vec();
    each(&mut out, f);
    FlexTensor::from_data(TensorData::new(out, shape))
}

/// `g = f(y, g)` element by element over two f32 tensors of one shape (the output and the
/// incoming gradient of an activation), in place in `g` when it owns its storage.
fn zip(y: FlexTensor, g: FlexTensor, f: impl Fn(f32, f32) -> f32) -> FlexTensor {
    assert_eq!(y.layout().shape(), g.layout().shape(), "activation backward: shapes differ");
    let y = y.to_contiguous();
    let ys = y.layout().start_offset();
    let n = y.layout().num_elements();
    let ys = &y.storage::<f32>()[ys..ys + n];
    let mut g = g;
    if !(g.is_unique() && g.layout().is_contiguous() && g.layout().start_offset() == 0) {
        g = g.to_contiguous();
    }
    if g.is_unique() && g.layout().start_offset() == 0 {
        each2(ys, &mut g.storage_mut::<f32>()[..n], f);
        return g;
    }
    let shape = g.layout().shape().clone();
    let gs = g.layout().start_offset();
    let mut out = g.storage::<f32>()[gs..gs + n].to_vec();
    each2(ys, &mut out, f);
    FlexTensor::from_data(TensorData::new(out, shape))
}

/// `v[i] = f(v[i])`, compiled for AVX2 where the CPU has it: twice the vector width of the
/// x86-64 baseline, and the same bits (no FMA is enabled, so nothing is contracted).
fn each(v: &mut [f32], f: impl Fn(f32) -> f32) {
    #[inline(always)]
    fn plain(v: &mut [f32], f: impl Fn(f32) -> f32) {
        for x in v {
            *x = f(*x);
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2(v: &mut [f32], f: impl Fn(f32) -> f32) {
        plain(v, f)
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { avx2(v, f) };
    }
    plain(v, f)
}

/// `g[i] = f(y[i], g[i])`, compiled for AVX2 as [`each`].
fn each2(y: &[f32], g: &mut [f32], f: impl Fn(f32, f32) -> f32) {
    #[inline(always)]
    fn plain(y: &[f32], g: &mut [f32], f: impl Fn(f32, f32) -> f32) {
        for (g, y) in g.iter_mut().zip(y) {
            *g = f(*y, *g);
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2(y: &[f32], g: &mut [f32], f: impl Fn(f32, f32) -> f32) {
        plain(y, g, f)
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { avx2(y, g, f) };
    }
    plain(y, g, f)
}

/// e^x (Cephes `expf`), for x clamped to [-87, 88] so that 2^n stays a normal float.
#[inline(always)]
#[allow(clippy::excessive_precision)] // Cephes' coefficients as published
fn exp_f32(x: f32) -> f32 {
    // Adding 1.5 * 2^23 rounds to an integer n, which then sits in the low mantissa bits.
    const MAGIC: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * std::f32::consts::LOG2_E + MAGIC;
    let n = t - MAGIC;
    // x - n ln 2 in two parts (ln 2 = 0.693359375 - 2.12194440e-4), exact for |n| <= 128.
    let r = x - n * 0.693_359_375 + n * 2.121_944_40e-4;
    let p = (((((1.987_569_150_0e-4 * r + 1.398_199_950_7e-3) * r + 8.333_451_907_3e-3) * r
        + 4.166_579_589_4e-2)
        * r
        + 1.666_666_545_9e-1)
        * r
        + 5.000_000_120_1e-1)
        * (r * r)
        + r
        + 1.0;
    // Wrapping: a NaN input leaves garbage bits here, and p is NaN anyway.
    let n_bits = (t.to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32);
    f32::from_bits((n_bits.wrapping_add(127) << 23) as u32) * p
}

/// tanh (Cephes `tanhf`): an odd polynomial under |x| < 0.625, 1 - 2 / (e^2|x| + 1) above.
#[inline(always)]
#[allow(clippy::excessive_precision)] // Cephes' coefficients as published
pub fn tanh_f32(x: f32) -> f32 {
    let z = x * x;
    let small = ((((-5.704_988_727_45e-3 * z + 2.063_908_879_54e-2) * z - 5.373_971_555_31e-2)
        * z
        + 1.333_144_220_36e-1)
        * z
        - 3.333_328_194_22e-1)
        * z
        * x
        + x;
    let a = x.abs();
    let large = (1.0 - 2.0 / (exp_f32(a + a) + 1.0)).copysign(x);
    if a < 0.625 {
        small
    } else {
        large
    }
}

/// The logistic function 1 / (1 + e^-x).
#[inline(always)]
pub fn sigmoid_f32(x: f32) -> f32 {
    1.0 / (1.0 + exp_f32(-x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place between two finite f32 of the same sign (or zero).
    fn ulps(a: f32, b: f32) -> u32 {
        let key = |x: f32| {
            let b = x.to_bits() as i32;
            if b < 0 {
                i32::MIN.wrapping_sub(b)
            } else {
                b
            }
        };
        key(a).abs_diff(key(b))
    }

    /// Every f32 in [-lo, hi] with a step of `step` bit patterns, both signs.
    fn dense(hi: f32, step: usize) -> impl Iterator<Item = f32> {
        (0..=hi.to_bits())
            .step_by(step)
            .flat_map(|b| [f32::from_bits(b), -f32::from_bits(b)])
    }

    /// Largest error in ulps against the f64 value rounded to f32, of ours and of libm's f32; and
    /// on how many of how many inputs ours and libm's differ.
    fn worst(
        f: impl Fn(f32) -> f32,
        libm: impl Fn(f32) -> f32,
        exact: impl Fn(f64) -> f64,
        hi: f32,
    ) -> (u32, u32, usize, usize) {
        let (mut ours, mut theirs, mut differ, mut n) = (0, 0, 0, 0);
        for x in dense(hi, 97) {
            let want = exact(x as f64) as f32;
            let (u, l) = (ulps(f(x), want), ulps(libm(x), want));
            assert!(u <= 2, "x = {x:e}: {} against {want} ({u} ulps)", f(x));
            ours = ours.max(u);
            theirs = theirs.max(l);
            differ += (f(x) != libm(x)) as usize;
            n += 1;
        }
        (ours, theirs, differ, n)
    }

    #[test]
    fn tanh_is_within_two_ulps_of_exact() {
        let (ours, libm, differ, n) = worst(tanh_f32, f32::tanh, f64::tanh, 20.0);
        println!("tanh: worst {ours} ulps (libm {libm}); differs from libm on {differ} of {n}");
        for x in [0.0f32, -0.0, 1e-30, 50.0, 1e30, f32::INFINITY] {
            assert_eq!(tanh_f32(x), x.tanh(), "tanh({x})");
            assert_eq!(tanh_f32(-x), (-x).tanh(), "tanh(-{x})");
        }
        assert!(tanh_f32(f32::NAN).is_nan());
        // The vectorized loop (AVX2 where the CPU has it) gives the scalar function's bits.
        let xs: Vec<f32> = dense(20.0, 4999).collect();
        let mut v = xs.clone();
        each(&mut v, tanh_f32);
        assert!(xs.iter().zip(&v).all(|(x, y)| tanh_f32(*x).to_bits() == y.to_bits()));
        let mut g = vec![0.5f32; xs.len()];
        each2(&v, &mut g, |y, g| g * (1.0 - y * y));
        assert!(v.iter().zip(&g).all(|(y, g)| (0.5 * (1.0 - y * y)).to_bits() == g.to_bits()));
    }

    #[test]
    fn sigmoid_is_within_two_ulps_of_exact() {
        let exact = |x: f64| 1.0 / (1.0 + (-x).exp());
        // flex's sigmoid (libm expf).
        let libm = |x: f32| {
            if x >= 0.0 {
                1.0 / (1.0 + (-x).exp())
            } else {
                let e = x.exp();
                e / (1.0 + e)
            }
        };
        // Below -80 the result is under 2e-35: ours flushes towards 6e-39 (e^88 is the clamp).
        let (ours, libm, differ, n) = worst(sigmoid_f32, libm, exact, 80.0);
        println!("sigmoid: worst {ours} ulps (libm {libm}); differs from libm on {differ} of {n}");
        assert_eq!(sigmoid_f32(0.0), 0.5);
        assert_eq!(sigmoid_f32(100.0), 1.0);
        assert!(sigmoid_f32(-100.0) < 1e-38 && sigmoid_f32(-100.0) >= 0.0);
        assert!(sigmoid_f32(f32::NAN).is_nan());
        let xs: Vec<f32> = dense(80.0, 4999).collect();
        let mut v = xs.clone();
        each(&mut v, sigmoid_f32);
        assert!(xs.iter().zip(&v).all(|(x, y)| sigmoid_f32(*x).to_bits() == y.to_bits()));
    }

    /// Values and gradients through burn's autodiff equal burn's own tanh and sigmoid to a few ulps,
    /// on a tensor that is a strided view (the transpose) as the layers hand over.
    #[test]
    fn autodiff_matches_burns_activations() {
        let device = Device::flex().autodiff();
        let v: Vec<f32> = (0..600)
            .map(|i| (i as f32 * 0.37).sin() * 12.0 - 0.3)
            .collect();
        let w: Vec<f32> = (0..600).map(|i| (i as f32 * 0.11).cos()).collect();
        let run = |fast: bool| {
            let x = Tensor::<2>::from_data(TensorData::new(v.clone(), [20, 30]), &device)
                .require_grad();
            let w = Tensor::<2>::from_data(TensorData::new(w.clone(), [30, 20]), &device);
            let xt = x.clone().transpose();
            let (t, s) = if fast {
                (tanh(xt.clone()), sigmoid(xt * 0.5))
            } else {
                (
                    xt.clone().tanh(),
                    burn::tensor::activation::sigmoid(xt * 0.5),
                )
            };
            let out = (t.clone() * w.clone() + s.clone() * w * 3.0).sum();
            let g = x.grad(&out.backward()).unwrap();
            let vals = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
            (vals(t), vals(s), g.into_data().try_to_vec::<f32>().unwrap())
        };
        let (fast, burn) = (run(true), run(false));
        for (name, a, b) in [
            ("tanh", &fast.0, &burn.0),
            ("sigmoid", &fast.1, &burn.1),
            ("grad", &fast.2, &burn.2),
        ] {
            assert_eq!(a.len(), b.len());
            for (i, (a, b)) in a.iter().zip(b).enumerate() {
                // 1 - y^2 near y = 1 magnifies a one-ulp difference of y: an absolute floor.
                assert!(
                    (a - b).abs() <= 1e-6 * b.abs() + 2e-7,
                    "{name}[{i}]: {a} against {b}"
                );
            }
        }
        // Without autodiff too (evaluation takes this path).
        let x = Tensor::<1>::from_data(TensorData::new(v.clone(), [600]), &Device::flex());
        let (a, b) = (
            tanh(x.clone()).into_data().try_to_vec::<f32>().unwrap(),
            x.tanh().into_data().try_to_vec::<f32>().unwrap(),
        );
        assert!(a.iter().zip(&b).all(|(a, b)| ulps(*a, *b) <= 3));
    }

    #[test]
    fn exp_is_within_two_ulps_of_exact() {
        for x in dense(87.0, 31).filter(|x| *x <= 87.0 && *x >= -87.0) {
            let want = (x as f64).exp() as f32;
            assert!(
                ulps(exp_f32(x), want) <= 1,
                "exp({x:e}) = {} against {want}",
                exp_f32(x)
            );
        }
    }
}
