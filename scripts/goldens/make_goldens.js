#!/usr/bin/env node
// Writes reference outputs of the TF.js graph models for fixed input tensors, computed by
// TensorFlow.js itself (pure-JS CPU backend), so the C++ runtime (core/io/tfjs_graph) can be
// checked against them. Inputs are synthetic float tensors (not images) so that image decoding
// and resizing play no part in the comparison. nsfwjs's Keras layers model (MobileNetV2) is run
// through tfjs-layers, and the outputs of chosen layers are written (core/model/mobilenet_v2);
// so is the ESRGAN-family x2 upscaler of @upscalerjs/esrgan-slim (core/model/keras_net).
//
// Usage: node make_goldens.js --models DIR --out DIR --deps DIR
//   --deps: an npm prefix holding @tensorflow/tfjs-core, -backend-cpu, -converter and -layers (4.22.0).
// Output: OUT/manifest.json and OUT/<model>.<tensor>.f32 (raw little-endian float32). The layers
// models go under manifest.layers_models (each absent when its model is not installed).
'use strict';
const fs = require('fs');
const path = require('path');

function arg(name) {
  const i = process.argv.indexOf('--' + name);
  if (i < 0 || i + 1 >= process.argv.length) {
    console.error(`make_goldens.js: missing --${name} DIR`);
    process.exit(2);
  }
  return process.argv[i + 1];
}

const modelsDir = arg('models');
const outDir = arg('out');
const deps = path.join(arg('deps'), 'node_modules');
const tf = require(path.join(deps, '@tensorflow/tfjs-core'));
require(path.join(deps, '@tensorflow/tfjs-backend-cpu'));
const converter = require(path.join(deps, '@tensorflow/tfjs-converter'));
const layers = require(path.join(deps, '@tensorflow/tfjs-layers'));

// nsfwjs's MobileNetV2 (ImageNet through block_10): layers whose outputs are compared.
const NSFWJS_TAPS = ['Conv1_relu', 'expanded_conv_project_BN', 'block_1_expand_relu', 'block_2_add',
  'block_3_expand_relu', 'block_5_add', 'block_6_expand_relu', 'block_9_add', 'block_10_depthwise_relu',
  'block_10_project_BN'];

// Models the app runs, their input node, value range and the outputs compared.
const MODELS = [
  {name: 'blazeface-front', input: 'input', range: [-1, 1], outputs: ['Identity', 'Identity_1', 'Identity_2', 'Identity_3']},
  {name: 'blazeface-back', input: 'input', range: [-1, 1], outputs: ['Identity', 'Identity_1', 'Identity_2', 'Identity_3']},
  {name: 'facemesh', input: 'input_1', range: [0, 1], outputs: ['Identity', 'Identity_1', 'Identity_2']},
  {name: 'selfie', input: 'input_1', range: [0, 1], outputs: ['activation_10', 'segment_add']},
  {name: 'mobilefacenet', input: 'img_inputs', range: [0, 255], outputs: ['embeddings']},
];

// Reads model.json and its shards from disk (no fetch in Node).
function fileHandler(jsonPath) {
  return {
    load: async () => {
      const model = JSON.parse(fs.readFileSync(jsonPath, 'utf8'));
      const specs = [];
      const buffers = [];
      for (const group of model.weightsManifest) {
        for (const p of group.paths) buffers.push(fs.readFileSync(path.join(path.dirname(jsonPath), p)));
        specs.push(...group.weights);
      }
      const all = Buffer.concat(buffers);
      return {
        modelTopology: model.modelTopology,
        format: model.format,
        generatedBy: model.generatedBy,
        convertedBy: model.convertedBy,
        signature: model.signature,
        userDefinedMetadata: model.userDefinedMetadata,
        weightSpecs: specs,
        weightData: all.buffer.slice(all.byteOffset, all.byteOffset + all.byteLength),
      };
    },
  };
}

// A smooth, image-like pattern with a little deterministic noise, in [lo, hi].
function fixedInput(shape, range, seed) {
  const [n, h, w, c] = shape;
  const data = new Float32Array(n * h * w * c);
  let state = seed >>> 0;
  for (let y = 0; y < h; ++y) {
    for (let x = 0; x < w; ++x) {
      for (let k = 0; k < c; ++k) {
        state = (Math.imul(state, 1664525) + 1013904223) >>> 0;
        const noise = state / 4294967296 - 0.5;
        const u = x / w, v = y / h;
        const cx = u - 0.5, cy = v - 0.45;
        const blob = Math.exp(-(cx * cx + cy * cy) / 0.06);
        let t = 0.35 + 0.4 * blob + 0.12 * Math.sin(9 * u + 2 * k) * Math.cos(7 * v) + 0.03 * noise;
        t = Math.min(1, Math.max(0, t));
        data[(y * w + x) * c + k] = range[0] + (range[1] - range[0]) * t;
      }
    }
  }
  return data;
}

// A Keras layers model from its {modelTopology, weightsManifest} and a reader of each shard's
// bytes (by manifest path).
async function loadLayers(artifacts, readShard) {
  const specs = [];
  const buffers = [];
  for (const group of artifacts.weightsManifest) {
    for (const p of group.paths) buffers.push(readShard(p));
    specs.push(...group.weights);
  }
  const all = Buffer.concat(buffers);
  return layers.loadLayersModel({
    load: async () => ({
      modelTopology: artifacts.modelTopology,
      weightSpecs: specs,
      weightData: all.buffer.slice(all.byteOffset, all.byteOffset + all.byteLength),
    }),
  });
}

// The nsfwjs files are CommonJS modules: model.min.js exports {modelTopology, weightsManifest},
// the shard module exports the weights as one base64 string.
async function nsfwjsGoldens(manifest, seed) {
  const dir = path.join(modelsDir, 'nsfwjs');
  const modelFile = path.join(dir, 'model.min.js');
  if (!fs.existsSync(modelFile)) {
    console.log(`goldens: ${modelFile} not installed (scripts/setup); nsfwjs goldens skipped`);
    return;
  }
  const model = await loadLayers(require(modelFile), (p) =>
    Buffer.from(require(path.join(dir, p + '.min.js')), 'base64'));
  const taps = layers.model({inputs: model.inputs, outputs: NSFWJS_TAPS.map((n) => model.getLayer(n).output)});
  const dims = [1, 224, 224, 3];
  const data = fixedInput(dims, [-1, 1], seed);
  const input = tf.tensor(data, dims, 'float32');
  const outs = taps.predict(input);
  const entry = {name: 'nsfwjs', model: 'nsfwjs/model.min.js', inputs: [], outputs: []};
  const inFile = 'nsfwjs.input.f32';
  fs.writeFileSync(path.join(outDir, inFile), Buffer.from(data.buffer));
  entry.inputs.push({name: 'input_1', shape: dims, file: inFile});
  for (let i = 0; i < outs.length; ++i) {
    const values = await outs[i].data();
    const file = `nsfwjs.${NSFWJS_TAPS[i]}.f32`;
    fs.writeFileSync(path.join(outDir, file), Buffer.from(new Float32Array(values).buffer));
    entry.outputs.push({name: NSFWJS_TAPS[i], shape: outs[i].shape, file});
  }
  manifest.layers_models = (manifest.layers_models || []).concat([entry]);
  tf.dispose([input, ...outs]);
  console.log(`goldens: nsfwjs done (${entry.outputs.map((o) => o.name + '[' + o.shape + ']').join(', ')})`);
}

// The esrgan-slim x2 upscaler: a plain model.json with a raw binary shard; its whole output for
// a small fixed input in its own range (0..255).
async function esrganGoldens(manifest, seed) {
  const dir = path.join(modelsDir, 'esrgan-slim-x2');
  const modelFile = path.join(dir, 'model.json');
  if (!fs.existsSync(modelFile)) {
    console.log(`goldens: ${modelFile} not installed (scripts/setup); esrgan-slim goldens skipped`);
    return;
  }
  const model = await loadLayers(JSON.parse(fs.readFileSync(modelFile, 'utf8')), (p) =>
    fs.readFileSync(path.join(dir, p)));
  const dims = [1, 20, 28, 3];
  const data = fixedInput(dims, [0, 255], seed);
  const input = tf.tensor(data, dims, 'float32');
  const out = model.predict(input);
  const entry = {name: 'esrgan-slim-x2', model: 'esrgan-slim-x2/model.json', inputs: [], outputs: []};
  fs.writeFileSync(path.join(outDir, 'esrgan-slim-x2.input.f32'), Buffer.from(data.buffer));
  entry.inputs.push({name: 'LR', shape: dims, file: 'esrgan-slim-x2.input.f32'});
  const values = await out.data();
  fs.writeFileSync(path.join(outDir, 'esrgan-slim-x2.SR.f32'), Buffer.from(new Float32Array(values).buffer));
  entry.outputs.push({name: 'SR', shape: out.shape, file: 'esrgan-slim-x2.SR.f32'});
  manifest.layers_models = (manifest.layers_models || []).concat([entry]);
  tf.dispose([input, out]);
  console.log(`goldens: esrgan-slim-x2 done (SR[${out.shape}])`);
}

async function main() {
  await tf.setBackend('cpu');
  fs.mkdirSync(outDir, {recursive: true});
  const manifest = {tfjs_version: tf.version_core, models: []};
  let seed = 12345;
  for (const m of MODELS) {
    const jsonPath = path.join(modelsDir, m.name + '.json');
    const model = await converter.loadGraphModel(fileHandler(jsonPath));
    const placeholder = model.artifacts.modelTopology.node.find((n) => n.name === m.input);
    const dims = placeholder.attr.shape.shape.dim.map((d) => Number(d.size));
    dims[0] = 1;
    const data = fixedInput(dims, m.range, seed++);
    const input = tf.tensor(data, dims, 'float32');
    const outs = model.execute({[m.input]: input}, m.outputs);
    const list = Array.isArray(outs) ? outs : [outs];
    const entry = {name: m.name, model: m.name + '.json', inputs: [], outputs: []};
    const inFile = `${m.name}.input.f32`;
    fs.writeFileSync(path.join(outDir, inFile), Buffer.from(data.buffer));
    entry.inputs.push({name: m.input, shape: dims, file: inFile});
    for (let i = 0; i < list.length; ++i) {
      const values = await list[i].data();
      const file = `${m.name}.${m.outputs[i]}.f32`;
      fs.writeFileSync(path.join(outDir, file), Buffer.from(new Float32Array(values).buffer));
      entry.outputs.push({name: m.outputs[i], shape: list[i].shape, file});
    }
    manifest.models.push(entry);
    tf.dispose([input, ...list]);
    console.log(`goldens: ${m.name} done (${entry.outputs.map((o) => o.name + '[' + o.shape + ']').join(', ')})`);
  }
  await nsfwjsGoldens(manifest, seed++);
  await esrganGoldens(manifest, seed++);
  fs.writeFileSync(path.join(outDir, 'manifest.json'), JSON.stringify(manifest, null, 1));
}

main().catch((e) => {
  console.error('make_goldens.js failed: ' + (e && e.stack ? e.stack : e));
  process.exit(1);
});
