// Runs the Khronos glTF validator (npm `gltf-validator`, installed by scripts/test into
// $LIVEBAKE_NODE_TOOLS) on one .gltf file, external resources read from beside it, and prints
// its report as JSON on stdout.
//   node validate.cjs NODE_TOOLS_DIR FILE.gltf
const fs = require("fs");
const path = require("path");

const [tools, file] = process.argv.slice(2);
const validator = require(path.join(tools, "node_modules", "gltf-validator"));
const dir = path.dirname(file);

validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), {
    uri: path.basename(file),
    maxIssues: 0,
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        fs.readFile(path.join(dir, decodeURIComponent(uri)), (err, data) =>
          err ? reject(err.toString()) : resolve(new Uint8Array(data)),
        );
      }),
  })
  .then((report) => process.stdout.write(JSON.stringify(report, null, 1)))
  .catch((error) => {
    process.stderr.write(`validator failed: ${error}\n`);
    process.exit(2);
  });
