// Run a Python script under MicroPython (WebAssembly port) with the firmware importable.
//
//   node tools/micropython/run.mjs [--heapsize BYTES[k|m]] SCRIPT.py
//
// Loads @micropython/micropython-webassembly-pyscript (pinned in package.json /
// package-lock.json next to this file; install with `npm ci --prefix tools/micropython`),
// copies lodestar/__init__.py, lodestar/contract.py and every firmware/*.py of the repository
// into the in-memory filesystem as /lib/lodestar/ and /lib/lodestar/firmware/, puts /lib on
// sys.path, runs SCRIPT.py as __main__ and prints its output.  Exit status: 0 when the script
// finished, 1 when it raised (the traceback goes to stderr), 2 for a usage error.
//
// A line that is exactly `#@split` cuts the script into parts run one after another by
// separate mp.runPython calls sharing __main__'s globals.  This port's garbage collector
// only frees objects allocated by *earlier* calls (gc.collect() during a call leaves that
// call's garbage, which the conservative stack scan still sees), so a script that measures
// live memory with gc.mem_alloc() must collect in a new part.

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, "..", "..");

function usage(message) {
  process.stderr.write(`run.mjs: ${message}\n` +
    "usage: node tools/micropython/run.mjs [--heapsize BYTES[k|m]] SCRIPT.py\n");
  process.exit(2);
}

function parseSize(text) {
  const match = /^(\d+)([kKmM]?)$/.exec(text);
  if (!match) usage(`bad heap size ${JSON.stringify(text)}`);
  const scale = { "": 1, k: 1024, m: 1024 * 1024 }[match[2].toLowerCase()];
  return Number(match[1]) * scale;
}

let heapsize = 1024 * 1024;
let script = null;
const args = process.argv.slice(2);
for (let i = 0; i < args.length; i++) {
  if (args[i] === "--heapsize" && i + 1 < args.length) {
    heapsize = parseSize(args[++i]);
  } else if (script === null) {
    script = args[i];
  } else {
    usage(`unexpected argument ${JSON.stringify(args[i])}`);
  }
}
if (script === null) usage("no script given");

const code = fs.readFileSync(script, "utf8");
const stdout = (line) => process.stdout.write(line + "\n");
const stderr = (line) => process.stderr.write(line + "\n");
const mp = await loadMicroPython({ heapsize, stdout, stderr, linebuffer: true });

// The firmware package and the two lodestar files it imports.
function copy(source, target) {
  mp.FS.writeFile(target, fs.readFileSync(path.join(repo, source)));
}
mp.FS.mkdirTree("/lib/lodestar/firmware");
copy("lodestar/__init__.py", "/lib/lodestar/__init__.py");
copy("lodestar/contract.py", "/lib/lodestar/contract.py");
for (const name of fs.readdirSync(path.join(repo, "firmware")).sort()) {
  if (name.endsWith(".py")) copy(path.join("firmware", name), `/lib/lodestar/firmware/${name}`);
}

let status = 0;
try {
  mp.runPython("import sys\nif '/lib' not in sys.path:\n    sys.path.insert(0, '/lib')\n");
  for (const part of code.split(/^#@split[ \t]*$/m)) mp.runPython(part);
} catch (error) {
  if (error && error.name === "PythonError") {
    // error.message is the MicroPython traceback.
    process.stderr.write(String(error.message).replace(/\n?$/, "\n"));
    status = 1;
  } else {
    throw error;
  }
}
// Flush a last line the script printed without a newline (linebuffer holds it).
const mod = mp._module;
if (mod && mod._stdoutBuffer && mod._stdoutBuffer.length) {
  process.stdout.write(mod._textDecoder.decode(new Uint8Array(mod._stdoutBuffer)) + "\n");
}
process.exitCode = status;
