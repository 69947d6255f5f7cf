"""Stage 5, text: INSTRUCT-GRASP samples in, prompt and target tokens out.

The formatter writes a sample's grasp as KOSMOS-E's text (four representations) and parses it
back; the tokenizers (SentencePiece, KOSMOS-2's or one trained here) and the prompt layout turn
text into token ids, the image-slot mask and the loss mask.
"""
