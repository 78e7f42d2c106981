"""Content-based retrieval after Müller et al. 2005 and Müller & Röder 2006: relational
features, segmentation, the inverted index, relational matching, motion templates and
template classification. :mod:`.plugin` registers them."""
