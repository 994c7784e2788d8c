"""SPTPT: the Superpixel Tensor Pooling Tracker (Wu, Zhang, Cao, Yan, IEEE Access 2019).

Pure numerics: RGB frames in, boxes and likelihoods out. No file, video or
configuration I/O lives here; see the ``annotator`` package for the tool.
"""
