// Poses a scene.glb's skinned node with the page's own code (glb.js,
// skin.js) at scene time T and prints its posed positions as JSON, for
// psao-web/tests/skin.rs to compare with psao-scene's skinning.
//
//   node psao-web/tests/node/pose.mjs SCENE.glb INSTANCE T

import { readFileSync } from "node:fs";
import { parseGlb } from "../../page/glb.js";
import { NodeSkin } from "../../page/skin.js";

const [file, instance, t] = process.argv.slice(2);
const bytes = readFileSync(file);
const scene = parseGlb(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength));
const node = scene.nodes.find((n) => n.instance === Number(instance));
if (!node?.skin) throw new Error(`instance ${instance} has no skin in ${file}`);
const posed = new NodeSkin(node.skin, scene.meshes[node.mesh]).pose(Number(t));
process.stdout.write(JSON.stringify({ positions: Array.from(posed.positions), normals: Array.from(posed.normals) }));
