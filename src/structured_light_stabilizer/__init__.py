"""Python side of structured_light_stabilizer: the messages (generated, in
structured_light_stabilizer.msg) and the helpers the demo monitor and the
rostests share to compare the pipeline's outputs with the simulator's ground
truth (structured_light_stabilizer.evaluation)."""
