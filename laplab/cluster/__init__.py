"""Scale-out: rollout workers on Ray and one learner (DeepRacer's SageMaker / RoboMaker split).

Nothing here imports Ray at import time; :class:`laplab.cluster.launch.RayWorkers` does, when a job
asks for several workers or a cluster. See docs/scaleout.md.
"""
