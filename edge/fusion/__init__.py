"""Several camera boards, one map: per-board detections, their fusion into the canonical poses, and the service.

* :mod:`edge.fusion.detections`: what a board measured in one frame (plain data), its canonical wire form;
* :mod:`edge.fusion.uncertainty`: how sure a board is of each detection (calibration error model, pixel noise,
  image and marker quality, the edge of the view), and the builder the tracker's results go through;
* :mod:`edge.fusion.board`: what ``edge-ips start`` needs to be one board of several;
* :mod:`edge.fusion.clock`: the boards' clock offsets, estimated from the data (never trusted from the boards);
* :mod:`edge.fusion.track` and :mod:`edge.fusion.core`: one filter per rover; association, time alignment,
  handovers, staleness;
* :mod:`edge.fusion.offline`: ``edge-ips fuse DET1.jsonl DET2.jsonl ...``;
* :mod:`edge.fusion.lease` and :mod:`edge.fusion.service`: ``edge-ips fuse --broker URL``, one active fuser at a time;
* :mod:`edge.fusion.seams`: ``calibrate check`` across boards; :mod:`edge.fusion.doctor`: ``doctor --fusion``.
"""
