//! From float models to the fixed-point model blob the firmware runs: `quantize` (a model trained
//! here), `import` (the published model), `model_blob` (a blob from a training folder, for the demo
//! and the tests).
pub mod quantize;
pub mod import;
pub mod model_blob;
