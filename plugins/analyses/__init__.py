"""Generic analyses of a motions dataset. :mod:`.plugin` registers them."""
