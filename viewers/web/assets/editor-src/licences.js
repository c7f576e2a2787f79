// Prints the licence of every package bundled into wart-editor.js (for wart-editor.LICENSES.txt).
const fs = require("fs");
const path = require("path");
const lock = JSON.parse(fs.readFileSync("package-lock.json", "utf8"));
const out = ["Licences of the packages bundled into wart-editor.js (by build-editor.sh).", ""];
for (const key of Object.keys(lock.packages).sort()) {
  if (!key.startsWith("node_modules/") || key.includes("esbuild")) continue;
  const dir = key;
  const meta = JSON.parse(fs.readFileSync(path.join(dir, "package.json"), "utf8"));
  const file = fs.readdirSync(dir).find((f) => /^licen[cs]e/i.test(f));
  out.push(`== ${meta.name} ${meta.version} (${meta.license})`);
  out.push(file ? fs.readFileSync(path.join(dir, file), "utf8").trim() : "(no licence file)");
  out.push("");
}
process.stdout.write(out.join("\n") + "\n");
