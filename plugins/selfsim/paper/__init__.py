"""The paper (Aristidou et al. 2018): motion textures and words, the exact KNN of motion
words, the movement digression map and its repair (§3-§4)."""
