"""The release wing: assemble the ReSTI-schema release (:mod:`.assemble`), publish it atomically into
a folder that is ours (:mod:`.publish`), verify it (:mod:`.verify`), rebuild only its options
(:mod:`.reoption`) and audit its answer interface (:mod:`.audit`)."""
