//! What evaluation and quantization need from a trained float model, whatever its kind.

/// Predicts the face a model expects for one observation.
pub trait FacePredictor {
    /// Face size (height, width) in pixels.
    fn face_size(&self) -> (usize, usize);

    /// `head` is [HeadYaw, HeadPitch] in radians (what a decoder uses); `face` is the observed crop,
    /// grey/255, row-major (what an autoencoder uses). Returns the predicted face, grey/255, row-major.
    fn predict(&self, head: [f32; 2], face: &[f32]) -> Vec<f32>;

    /// Many at once; models override this to batch.
    fn predict_batch(&self, heads: &[[f32; 2]], faces: &[Vec<f32>]) -> Vec<Vec<f32>> {
        heads.iter().zip(faces).map(|(h, f)| self.predict(*h, f)).collect()
    }
}
