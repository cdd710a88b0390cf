// Validate glTF files with the Khronos glTF-Validator (npm gltf-validator), and their
// USDAHD_lightmap_directional objects against docs/gltf/*.schema.json with ajv (JSON Schema
// 2020-12): prints one JSON object {file: {errors, warnings, infos, messages, schemaErrors}}.
// Usage: USDAHD_WEB_MODULES=<dir>/node_modules node validate.mjs SCHEMA_DIR a.glb b.gltf
import { createRequire } from 'module';
import fs from 'fs';
import path from 'path';

const require = createRequire(path.join(process.env.USDAHD_WEB_MODULES || '.', 'noop.js'));
const validator = require('gltf-validator');
const Ajv2020 = require('ajv/dist/2020').default;

const [schemaDir, ...files] = process.argv.slice(2);
const ajv = new Ajv2020({ allErrors: true, strict: false });
const EXT = 'USDAHD_lightmap_directional';
const rootSchema = ajv.compile(JSON.parse(fs.readFileSync(
  path.join(schemaDir, `glTF.${EXT}.schema.json`), 'utf8')));
const nodeSchema = ajv.compile(JSON.parse(fs.readFileSync(
  path.join(schemaDir, `node.${EXT}.schema.json`), 'utf8')));

function gltfJson(bytes) {
  const magic = new DataView(bytes.buffer, bytes.byteOffset).getUint32(0, true);
  if (magic !== 0x46546c67) return JSON.parse(new TextDecoder().decode(bytes));
  const n = new DataView(bytes.buffer, bytes.byteOffset).getUint32(12, true);
  return JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + n)));
}

function schemaErrors(doc) {
  const errs = [];
  const root = (doc.extensions || {})[EXT];
  if (!root) return [`no ${EXT} at the root`];
  if (!rootSchema(root)) errs.push(...rootSchema.errors.map((e) => `root${e.instancePath}: ${e.message}`));
  (doc.nodes || []).forEach((node, i) => {
    const ext = (node.extensions || {})[EXT];
    if (ext && !nodeSchema(ext)) {
      errs.push(...nodeSchema.errors.map((e) => `nodes/${i}${e.instancePath}: ${e.message}`));
    }
    if (ext && !(ext.page < root.pages.length)) errs.push(`nodes/${i}: page ${ext.page} out of range`);
  });
  return errs;
}

const out = {};
for (const file of files) {
  const bytes = new Uint8Array(fs.readFileSync(file));
  const dir = path.dirname(file);
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 100,
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        fs.readFile(path.join(dir, decodeURIComponent(uri)), (err, data) =>
          err ? reject(err.toString()) : resolve(new Uint8Array(data)));
      }),
  });
  out[file] = {
    errors: report.issues.numErrors,
    warnings: report.issues.numWarnings,
    infos: report.issues.numInfos,
    schemaErrors: schemaErrors(gltfJson(bytes)),
    messages: report.issues.messages.map((m) => `${m.severity} ${m.code} ${m.pointer || ''}: ${m.message}`),
  };
}
console.log(JSON.stringify(out, null, 1));
