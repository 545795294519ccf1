/* Prints the 8-bit grey pixels that png++'s image<gray_pixel> reads from a PNG, with the transforms
 * png++ asks libpng for: palette -> RGB -> grey (libpng's default weights), alpha stripped, 16 bits
 * stripped, 1/2/4-bit grey expanded. The KITTI devkit reads its object maps this way; the test
 * test_kitti_object_map_read_as_libpng_reads_it compares drlab's reader with it.
 * Usage: libpng_gray FILE.png  (prints "W H" and then the pixels, row by row; exits 3 before
 * libpng 1.5.5, whose grey weights differ from the 6968 / 23434 / 2366 drlab follows) */
#include <png.h>
#include <stdio.h>
#include <stdlib.h>

int main(int argc, char **argv) {
    if (argc != 2) return 2;
    if (png_access_version_number() < 10505) return 3;
    FILE *f = fopen(argv[1], "rb");
    if (!f) return 2;
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png_create_info_struct(png);
    if (setjmp(png_jmpbuf(png))) return 1;
    png_init_io(png, f);
    png_read_info(png, info);
    int type = png_get_color_type(png, info), depth = png_get_bit_depth(png, info);
    if (type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
    if (type == PNG_COLOR_TYPE_PALETTE || (type & PNG_COLOR_MASK_COLOR))
        png_set_rgb_to_gray(png, PNG_ERROR_ACTION_NONE, -1.0, -1.0);
    if ((type & PNG_COLOR_MASK_ALPHA) || png_get_valid(png, info, PNG_INFO_tRNS)) png_set_strip_alpha(png);
    if (depth == 16) png_set_strip_16(png);
    if (type == PNG_COLOR_TYPE_GRAY && depth < 8) png_set_expand_gray_1_2_4_to_8(png);
    png_read_update_info(png, info);
    png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
    png_bytep row = malloc(png_get_rowbytes(png, info));
    printf("%u %u\n", w, h);
    for (png_uint_32 y = 0; y < h; y++) {
        png_read_row(png, row, NULL);
        for (png_uint_32 x = 0; x < w; x++) printf("%d ", row[x]);
        printf("\n");
    }
    free(row);
    fclose(f);
    return 0;
}
