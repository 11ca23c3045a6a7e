// Poses a scene.glb's skinned or morphing node with the page's own code
// (glb.js, pose.js) at scene time T and prints its posed positions as JSON, for
// psao-web/tests/skin.rs to compare with psao-scene's skinning.
//
//   node psao-web/tests/node/pose.mjs SCENE.glb INSTANCE T

import { readFileSync } from "node:fs";
import { parseGlb } from "../../page/glb.js";
import { NodePose } from "../../page/pose.js";

const [file, instance, t] = process.argv.slice(2);
const bytes = readFileSync(file);
const scene = parseGlb(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength));
const node = scene.nodes.find((n) => n.instance === Number(instance));
if (!node?.skin && !node?.morph) throw new Error(`instance ${instance} neither skins nor morphs in ${file}`);
const posed = new NodePose(node.skin, node.morph, scene.meshes[node.mesh]).pose(Number(t));
process.stdout.write(JSON.stringify({ positions: Array.from(posed.positions), normals: Array.from(posed.normals) }));
