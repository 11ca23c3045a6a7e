# The bench set's metre-sized models in ../shared/scenes (paths under it),
# sourced by scripts/bench-set.sh and scripts/client-time-set.sh so both
# run the same scenes.
metre_models=(AnimatedMorphCube/AnimatedMorphCube.glb AnimatedTriangle/AnimatedTriangle.gltf
              BoxAnimated/BoxAnimated.glb Cameras/Cameras.gltf CesiumMilkTruck/CesiumMilkTruck.gltf
              MorphPrimitivesTest/MorphPrimitivesTest.gltf NegativeScaleTest/NegativeScaleTest.gltf
              RiggedFigure/RiggedFigure.glb RiggedSimple/RiggedSimple.glb SimpleSkin/SimpleSkin.gltf)
