"""Instruction understanding: what an instruction asks for, in words, before anything looks at the scene's points.

Typical use::

    from abm.language import decompose_instruction, resolve_instruction, split_roles

    target, skill = decompose_instruction("put the tomato in the plate")   # "tomato", "put X in the plate"
    split_roles("put the ketchup in the bowl")                           # (("ketchup", "bowl"), "put X in Y")
    resolve_instruction("grab the yellow one", ["target", "red block", "yellow block"]).canonical
    # -> "put the yellow block on the target" (plain words onto the scene's objects)

* :mod:`~abm.language.instruction`: the template parser (``templates.yaml``): instruction -> skill text + X (and Y);
* :mod:`~abm.language.one_command`: the refusal of what is not one positive command (negations, conditions, ...);
* :mod:`~abm.language.resolve`: plain words onto one object of the scene and one known skill, with a confidence;
* :mod:`~abm.language.roles`: an instruction's sub-goal objects, skill text and destination, as every consumer
  (training data, conditioning, evaluation, viewer, ``abm run``) splits it.

**Layer.** Below :mod:`abm.grounding` (which grounds the X this package names) and above :mod:`abm.sim`: the
vocabulary of instructions is the benchmark's. Each task declares its skills, the catalog categories it acts on and
its destination (:data:`abm.sim.tasks.TASKS`), and the resolver matches words against the object catalog's names,
colours and categories (:data:`abm.sim.catalog.CATALOG`). Both are data modules that load no MuJoCo, so this
package runs without the ``sim`` extra. Nothing here loads torch.
"""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy)
    from abm.language.instruction import (
        InstructionError,
        InstructionParser,
        MultiStepInstructionError,
        NotOneCommandError,
        ParsedInstruction,
        RewritingParser,
        TemplateParser,
        TemplateSet,
        clip_prompt,
        decompose_instruction,
        load_templates,
        normalize_instruction,
        require_instruction,
    )
    from abm.language.resolve import (
        RESOLVE_MIN_CONFIDENCE,
        Resolution,
        UnresolvedInstructionError,
        resolve_instruction,
    )
    from abm.language.roles import destination_for, instruction_destination, split_instruction, split_roles

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = [
    "InstructionError", "InstructionParser", "MultiStepInstructionError", "NotOneCommandError", "ParsedInstruction",
    "RewritingParser", "TemplateParser", "TemplateSet", "clip_prompt", "decompose_instruction", "load_templates",
    "normalize_instruction", "require_instruction",
    "RESOLVE_MIN_CONFIDENCE", "Resolution", "UnresolvedInstructionError", "resolve_instruction",
    "destination_for", "instruction_destination", "split_instruction", "split_roles",
]
