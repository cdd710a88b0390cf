// Validate glTF files with the Khronos glTF-Validator (npm gltf-validator): prints one JSON
// object {file: {errors, warnings, infos, messages}} for the files given as arguments.
// Usage: NODE_PATH=<dir>/node_modules node validate.mjs a.glb b.gltf
import { createRequire } from 'module';
import fs from 'fs';
import path from 'path';

const require = createRequire(path.join(process.env.USDAHD_WEB_MODULES || '.', 'noop.js'));
const validator = require('gltf-validator');

const out = {};
for (const file of process.argv.slice(2)) {
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
    messages: report.issues.messages.map((m) => `${m.severity} ${m.code} ${m.pointer || ''}: ${m.message}`),
  };
}
console.log(JSON.stringify(out, null, 1));
