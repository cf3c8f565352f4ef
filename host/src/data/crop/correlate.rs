//! The exact cross-correlation of a template over every window of a frame, by FFT.
use image::GrayImage;
use rustfft::num_complex::Complex;

/// Cross-correlation of `tpl` over every window of `frame` (row-major, `(fh-th+1) x (fw-tw+1)`),
/// exact.
///
/// By FFT in f64: the circular correlation of the frame with the zero-padded template equals the
/// linear one on every whole window (no window wraps), every value is an integer below 2^33,
/// and the transforms' rounding error (about 1e-6 here) is far below 0.5, so rounding gives the
/// exact sums. The template's spectrum and the plans are kept per thread for the next frame.
pub fn cross_correlation(frame: &GrayImage, tpl: &GrayImage) -> Vec<i64> {
    thread_local! {
        static CORRELATOR: std::cell::RefCell<Option<Correlator>> = const { std::cell::RefCell::new(None) };
    }
    CORRELATOR.with_borrow_mut(|slot| {
        let fits = slot.as_ref().is_some_and(|c| c.fits(frame, tpl));
        if !fits {
            *slot = Some(Correlator::new(frame.width() as usize, frame.height() as usize, tpl));
        }
        slot.as_mut().expect("just set").correlate(frame)
    })
}

/// FFT plans for one frame size and the spectrum of one template.
struct Correlator {
    fw: usize,
    fh: usize,
    tpl: GrayImage,
    r2c: std::sync::Arc<dyn realfft::RealToComplex<f64>>,
    c2r: std::sync::Arc<dyn realfft::ComplexToReal<f64>>,
    col_fwd: std::sync::Arc<dyn rustfft::Fft<f64>>,
    col_inv: std::sync::Arc<dyn rustfft::Fft<f64>>,
    /// Conjugated template spectrum, column-major: frequency `(ky, kx)` at `kx * fh + ky`.
    tpl_spec: Vec<Complex<f64>>,
    spec: Vec<Complex<f64>>,
    row: Vec<f64>,
    row_spec: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
}

impl Correlator {
    fn new(fw: usize, fh: usize, tpl: &GrayImage) -> Correlator {
        let mut real = realfft::RealFftPlanner::<f64>::new();
        let mut complex = rustfft::FftPlanner::<f64>::new();
        let (r2c, c2r) = (real.plan_fft_forward(fw), real.plan_fft_inverse(fw));
        let (col_fwd, col_inv) = (complex.plan_fft_forward(fh), complex.plan_fft_inverse(fh));
        let scratch_len = [
            r2c.get_scratch_len(),
            c2r.get_scratch_len(),
            col_fwd.get_inplace_scratch_len(),
            col_inv.get_inplace_scratch_len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(0);
        let nc = fw / 2 + 1;
        let mut c = Correlator {
            fw,
            fh,
            tpl: tpl.clone(),
            r2c,
            c2r,
            col_fwd,
            col_inv,
            tpl_spec: Vec::new(),
            spec: vec![Complex::default(); nc * fh],
            row: vec![0.0; fw],
            row_spec: vec![Complex::default(); nc],
            scratch: vec![Complex::default(); scratch_len],
        };
        c.forward(tpl.as_raw(), tpl.width() as usize, tpl.height() as usize);
        c.tpl_spec = c.spec.iter().map(|v| v.conj()).collect();
        c
    }

    fn fits(&self, frame: &GrayImage, tpl: &GrayImage) -> bool {
        (frame.width() as usize, frame.height() as usize) == (self.fw, self.fh) && self.tpl == *tpl
    }

    /// `self.spec` = 2-D spectrum of the `w x h` image `px` zero-padded to the frame size.
    fn forward(&mut self, px: &[u8], w: usize, h: usize) {
        let (fh, nc) = (self.fh, self.fw / 2 + 1);
        self.spec.fill(Complex::default());
        for y in 0..h {
            self.row.fill(0.0);
            for (d, &v) in self.row.iter_mut().zip(&px[y * w..(y + 1) * w]) {
                *d = v as f64;
            }
            self.r2c
                .process_with_scratch(&mut self.row, &mut self.row_spec, &mut self.scratch)
                .expect("buffer sizes come from the plan");
            for (kx, &v) in self.row_spec.iter().enumerate() {
                self.spec[kx * fh + y] = v;
            }
        }
        debug_assert_eq!(self.spec.len(), nc * fh);
        self.col_fwd.process_with_scratch(&mut self.spec, &mut self.scratch);
    }

    fn correlate(&mut self, frame: &GrayImage) -> Vec<i64> {
        let (fw, fh, nc) = (self.fw, self.fh, self.fw / 2 + 1);
        let (tw, th) = (self.tpl.width() as usize, self.tpl.height() as usize);
        let (ow, oh) = (fw - tw + 1, fh - th + 1);
        self.forward(frame.as_raw(), fw, fh);
        for (v, t) in self.spec.iter_mut().zip(&self.tpl_spec) {
            *v *= t;
        }
        self.col_inv.process_with_scratch(&mut self.spec, &mut self.scratch);
        let scale = 1.0 / (fw * fh) as f64;
        let mut out = vec![0i64; ow * oh];
        for y in 0..oh {
            for (kx, d) in self.row_spec.iter_mut().enumerate() {
                *d = self.spec[kx * fh + y];
            }
            // The result is real: the DC (and, for an even width, the Nyquist) bin's imaginary
            // part is rounding noise, which the inverse real transform refuses.
            self.row_spec[0].im = 0.0;
            if fw % 2 == 0 {
                self.row_spec[nc - 1].im = 0.0;
            }
            self.c2r
                .process_with_scratch(&mut self.row_spec, &mut self.row, &mut self.scratch)
                .expect("buffer sizes come from the plan");
            for (o, &v) in out[y * ow..(y + 1) * ow].iter_mut().zip(&self.row) {
                *o = (v * scale).round() as i64;
            }
        }
        out
    }
}
